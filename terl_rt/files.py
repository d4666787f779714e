"""Output files written whole or not at all, and never silently over another run's.

Every file terl-rt writes (logs, CSV, JSON, reports, renders, layouts, checkpoints) is
written under a hidden temporary name beside its target and then published: with
`replace`, renamed over the target; without, linked to the target's name, which fails
when a file of that name exists, so two runs writing one path cannot replace each other
unseen (the check and the publication are one step). Errors name the target, never the
temporary file. A run that writes a file for a long time (an episode log) holds its path
(`OutputHold`): a second run asking for it meanwhile is refused, --force or not.
"""

from __future__ import annotations

import errno
import os
import secrets
import shutil
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO

__all__ = [
    "NamingFile", "OutputBusy", "OutputExists", "OutputHold", "atomic_output", "atomic_outputs", "publish",
    "temporary_beside",
]

try:
    import fcntl
except ImportError:  # Windows: outputs are not held
    fcntl = None  # type: ignore[assignment]


class OutputExists(FileExistsError):
    """The target of an output appeared while it was written (another run wrote it)."""


class OutputBusy(OSError):
    """Another run holds the output at this path (`OutputHold`)."""


class OutputHold:
    """Holds `path` for this run until `release`: an `OutputHold` of the same path taken
    meanwhile, in any process, raises OutputBusy naming the holder's pid.

    The hold is an advisory lock (flock) on a hidden file beside `path`, `.NAME.lock`,
    which holds the pid and is removed on release; the system drops the lock of a run
    that dies, and the next hold takes the file over. Not on Windows (no flock): there
    every hold is granted.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._lock = self._lock_of(self.path)
        self._fd: int | None = None
        if fcntl is not None:
            self._fd = self._take()

    def _take(self) -> int:
        """The descriptor of the lock file, locked; OutputBusy when another run holds it."""
        while True:
            fd = os.open(self._lock, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _holder(fd)
                os.close(fd)
                raise OutputBusy(
                    errno.EBUSY, f"another run (pid {holder}) is writing it; wait for it to end or choose another path",
                    str(self.path),
                ) from None
            if self._still_named(fd):
                os.ftruncate(fd, 0)
                os.write(fd, str(os.getpid()).encode())
                return fd
            os.close(fd)  # its holder released and removed it meanwhile: take the new one

    def _still_named(self, fd: int) -> bool:
        """True when the lock file's name still leads to the file `fd` locked."""
        try:
            return os.path.samestat(os.stat(self._lock), os.fstat(fd))
        except FileNotFoundError:
            return False

    @classmethod
    def holder(cls, path: str | os.PathLike) -> str | None:
        """The pid of the run that holds `path` now ("unknown" where it wrote none yet),
        None when no run does (not on Windows: None). Starts no hold: the lock file is
        probed with a shared lock for an instant, and never made."""
        if fcntl is None:
            return None
        try:
            fd = os.open(cls._lock_of(Path(path)), os.O_RDONLY)
        except OSError:
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _holder(fd)
        finally:
            os.close(fd)  # the shared lock, where taken, goes with it
        return None

    @staticmethod
    def _lock_of(path: Path) -> Path:
        """The lock file of `path`: `.NAME.lock` beside it."""
        return path.with_name(f".{path.name}.lock")

    def release(self) -> None:
        """Give the path back (the lock file is removed before it is unlocked)."""
        if self._fd is None:
            return
        self._lock.unlink(missing_ok=True)
        os.close(self._fd)
        self._fd = None


def _holder(fd: int) -> str:
    """The pid the holder wrote in the lock file open at `fd` ("unknown" before it has)."""
    return os.read(fd, 32).decode(errors="replace").strip() or "unknown"


def temporary_beside(path: str | os.PathLike) -> Path:
    """A hidden, unused name in `path`'s folder with `path`'s suffix (what a reader of the
    folder can tell apart: `.NAME.PID.RANDOM.partial.SUFFIX`)."""
    path = Path(path)
    return path.with_name(f".{path.stem}.{os.getpid()}.{secrets.token_hex(4)}.partial{path.suffix}")


def publish(temporary: str | os.PathLike, path: str | os.PathLike, replace: bool = False) -> None:
    """Give the complete file at `temporary` the name `path`, in one step.

    replace: rename over any file at `path`. Otherwise link `temporary` to `path` (or, on a
    filesystem without hard links, claim `path` with O_EXCL and rename over the claim),
    raising OutputExists when `path` exists. `temporary` is gone afterwards either way.
    """
    temporary, path = Path(temporary), Path(path)
    if replace:
        os.replace(temporary, path)
        return
    try:
        os.link(temporary, path)
    except FileExistsError:
        raise _exists(path) from None
    except OSError as error:
        if error.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV, errno.EMLINK):
            raise
        _claim(path)
        os.replace(temporary, path)
        return
    temporary.unlink()


def _claim(path: Path) -> None:
    """Create `path` empty, failing with OutputExists when it exists."""
    try:
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644))
    except FileExistsError:
        raise _exists(path) from None


def _exists(path: Path) -> OutputExists:
    return OutputExists(errno.EEXIST, "was written by another run meanwhile; pass --force to replace it", str(path))


def _named(error: OSError, target: Path) -> OSError:
    """`error` with `target` as its file name (same type, errno and reason)."""
    return type(error)(error.errno, error.strerror or str(error), str(target))


class NamingFile:
    """A binary file object written under a temporary name whose write, flush and close
    errors (a full disk, a file too large) name `path`, the file the user asked for."""

    def __init__(self, handle: BinaryIO, path: str | os.PathLike):
        self._handle, self._path = handle, Path(path)

    def write(self, data) -> int:
        return self._naming(self._handle.write, data)

    def flush(self) -> None:
        self._naming(self._handle.flush)

    def close(self) -> None:
        self._naming(self._handle.close)  # flushes what is buffered

    def _naming(self, call, *args):
        try:
            return call(*args)
        except OSError as error:
            raise _named(error, self._path) from error

    def __getattr__(self, name: str):
        return getattr(self._handle, name)


@contextmanager
def atomic_output(path: str | os.PathLike, replace: bool = False) -> Iterator[Path]:
    """Yield a temporary path beside `path` to write the whole output to; publish it at
    `path` (`publish`) when the block ends without an error, else remove it.

    An OSError raised while writing (a full disk, a file too large) names `path`, not the
    temporary file.
    """
    path = Path(path)
    temporary = temporary_beside(path)
    try:
        try:
            yield temporary
        except OSError as error:
            if error.filename not in (None, str(temporary)):
                raise
            raise _named(error, path) from error
        publish(temporary, path, replace)
    finally:
        temporary.unlink(missing_ok=True)


@contextmanager
def atomic_outputs(folder: str | os.PathLike, names: Sequence[str], replace: bool = False) -> Iterator[Path]:
    """Yield a hidden temporary folder inside `folder` to write the files `names` into;
    publish each at `folder`/name (`publish`, in order) when the block ends without an
    error; remove the temporary folder either way. OSErrors name `folder`'s files."""
    folder = Path(folder)
    staging = temporary_beside(folder / ".outputs")
    staging.mkdir()
    try:
        try:
            yield staging
        except OSError as error:
            if error.filename is not None and Path(error.filename).parent != staging:
                raise
            raise _named(error, folder / Path(error.filename or "").name) from error
        for name in names:
            publish(staging / name, folder / name, replace)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
