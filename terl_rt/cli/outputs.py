"""Output files of terl-rt commands: never over an input, never over a file unless --force.

Every command that writes checks its outputs before it starts work: an output that is
one of the command's own inputs is refused even with --force; an existing output is
refused unless --force; a missing folder is made and must take a file. Outputs are
written through `terl_rt.files.atomic_output` (logs: published at their first step), so
a run that fails early leaves an earlier file untouched and two runs on one path never
replace each other silently.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Iterable
from pathlib import Path

import click

from terl_rt.cli.options import BadInput
from terl_rt.files import temporary_beside

force_option = click.option(
    "--force", is_flag=True,
    help="Replace output files that already exist (never the command's own inputs).",
)


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """True when `a` and `b` name the same file (the same inode, or the same resolved path;
    os.path.realpath, unlike Path.resolve, gives a path for a symlink loop too)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def check_output(
    path: str | os.PathLike,
    option: str,
    inputs: Iterable[tuple[str, str | os.PathLike | None]] = (),
    force: bool = False,
) -> Path:
    """Check the output `path` of `option` (e.g. "--log") and make its folder.

    inputs: (option, path) of the command's input files (None: not given). Raises
    BadInput when `path` is one of them, is a folder or a device, or exists without --force.
    """
    if not str(path).strip():
        raise BadInput(f"{option} is empty; name a file")
    out = Path(path)
    for name, given in inputs:
        if given is not None and same_file(out, given):
            raise BadInput(f"{option} {out} is the {name} file of this command; it is never written over")
    if out.exists() or out.is_symlink():
        try:
            mode = out.stat().st_mode
        except OSError as error:
            raise BadInput(f"{option} {out}: {error.strerror}") from None
        if stat.S_ISDIR(mode):
            raise BadInput(f"{option} {out} is a folder; name a file")
        if not stat.S_ISREG(mode):
            raise BadInput(f"{option} {out} exists and is not a regular file; name a file")
        if not force:
            raise BadInput(f"{option} {out} exists; pass --force to replace it")
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise BadInput(f"{option} {out}: cannot make its folder ({error.strerror or error})") from None
    if not out.parent.is_dir():
        raise BadInput(f"{option} {out}: {out.parent} is not a folder")
    _check_writable(out, option)
    return out


def output_folder(path: str, option: str = "--out") -> Path:
    """The folder `option` names for a command's files (checked one by one with
    `check_output`); BadInput for an empty path or a file."""
    if not path.strip():
        raise BadInput(f"{option} is empty; name a folder")
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise BadInput(f"{option} {path} is a file; name a folder")
    return folder


def _check_writable(out: Path, option: str) -> None:
    """BadInput unless a file can be made in `out`'s folder (permissions, a read-only or
    full filesystem): said before the run, not after it."""
    probe = temporary_beside(out)
    made = False
    try:
        with open(probe, "xb") as handle:
            made = True
            handle.write(b"\0")
    except OSError as error:
        raise BadInput(f"{option} {out}: cannot write in {out.parent} ({error.strerror or error})") from None
    finally:
        if made:  # only what was made: a read-only disk refuses to remove even a file that is not there
            probe.unlink(missing_ok=True)
