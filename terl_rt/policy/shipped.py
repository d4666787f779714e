"""The shipped policies, found by name: `terl` is exported/terl.onnx of the checkout (or of
the working directory, else the copy installed with the package), any other name a file of
exported/comparison/ (`iqn-seed-1`: exported/comparison/iqn-seed-1.onnx), the paper's
comparison as a grid ships it."""

from __future__ import annotations

import importlib.resources
import os
from pathlib import Path

import terl_rt
from terl_rt.policy.onnx_policy import ContractError, OnnxPolicy

DEFAULT_NAME = "terl"
"""The name of the default policy."""
DEFAULT_POLICY = Path("exported") / "terl.onnx"
"""The default policy, relative to the repository checkout (or the working directory)."""
COMPARISON_FOLDER = Path("exported") / "comparison"
"""The paper's comparison, one file a method and seed, relative to the checkout."""
PACKAGED_POLICY = ("terl_rt.policy", "default/terl.onnx")
"""(package, resource) of the copy of the default policy installed with terl-rt: what an
installed terl-rt uses away from a checkout (tests/test_package.py keeps it identical to
exported/terl.onnx)."""


class NoShippedPolicy(FileNotFoundError):
    """No policy of the name asked for is here; the message says where it was looked for."""


def _roots() -> tuple[Path, Path]:
    """The checkout terl_rt was imported from, then the working directory."""
    return Path(terl_rt.__file__).resolve().parents[1], Path.cwd()


def packaged_policy_path() -> Path | None:
    """The default policy installed inside the terl_rt package, None when it is absent."""
    package, resource = PACKAGED_POLICY
    try:
        path = importlib.resources.files(package).joinpath(resource)
    except ModuleNotFoundError:
        return None
    # Installed packages are plain folders (setuptools does not zip them): a real path.
    return Path(str(path)) if path.is_file() else None


def default_policy_path() -> Path:
    """exported/terl.onnx of the checkout terl_rt was imported from, else of the working
    directory, else the copy installed with the package; NoShippedPolicy when none exists."""
    for root in _roots():
        if (root / DEFAULT_POLICY).is_file():
            return root / DEFAULT_POLICY
    packaged = packaged_policy_path()
    if packaged is not None:
        return packaged
    raise NoShippedPolicy(f"no policy at {DEFAULT_POLICY} yet")


def shipped_policy_path(name: str) -> Path:
    """The file of the shipped policy `name` (module docstring); NoShippedPolicy naming
    where it was looked for when there is none."""
    if name == DEFAULT_NAME:
        return default_policy_path()
    for root in _roots():
        if (root / COMPARISON_FOLDER / f"{name}.onnx").is_file():
            return root / COMPARISON_FOLDER / f"{name}.onnx"
    raise NoShippedPolicy(f"no policy file {name!r}, and no shipped policy of that name "
                          f"({DEFAULT_NAME}, or {COMPARISON_FOLDER}/{name}.onnx of a checkout)")


def policy_path(policy: str | os.PathLike | None) -> Path:
    """The file of `policy`: None is the default policy; a plain name (a str without a
    folder or suffix) that is no file here is a shipped policy's; anything else a path."""
    if policy is None:
        return default_policy_path()
    path = Path(policy)
    if isinstance(policy, str) and str(path) == path.name and not path.suffix and not path.exists():
        return shipped_policy_path(policy)
    return path


def open_policy(policy: str | os.PathLike | None, threads: int | None = None) -> OnnxPolicy:
    """The OnnxPolicy of `policy` (`policy_path`) with `threads` onnxruntime intra-op threads;
    a contract refusal names the file."""
    path = policy_path(policy)
    try:
        return OnnxPolicy(path, threads=threads)
    except ContractError as error:
        if str(path) in str(error):
            raise
        raise ContractError(f"{path}: {error}") from error
