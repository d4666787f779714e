"""Building the wheel of this checkout for the tests that install it."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCE_FILES = ("pyproject.toml", "README.md", "LICENSE", "CITATION.cff")
"""The files of the checkout a build reads besides terl_rt/."""


def build_wheel(folder: Path) -> Path:
    """The wheel of this checkout, built in `folder` from a copy of what a source
    distribution holds, so the build leaves nothing (build/, *.egg-info) in the checkout
    and no stale build output slips in. RuntimeError with pip's last words when it fails."""
    source = folder / "source"
    source.mkdir()
    for name in SOURCE_FILES:
        shutil.copy(ROOT / name, source / name)
    for package in ("terl_rt", "training"):
        shutil.copytree(ROOT / package, source / package, ignore=shutil.ignore_patterns("__pycache__"))
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", folder / "dist", source],
        capture_output=True, text=True,
    )
    if build.returncode != 0:
        raise RuntimeError(build.stderr.strip()[-300:])
    return next((folder / "dist").glob("terl_rt-*.whl"))
