"""The issue-43 check, end to end: the wheel of this checkout installed into a fresh
virtual environment (its dependencies from the package index), used from another folder.

Slow (about 50 s on the 2-core machine with a warm pip cache: the venv, the installs), so out of CI: run it with
`python -m pytest tests/test_wheel.py -m slow -q`.
"""

from __future__ import annotations

import json
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest
from wheels import build_wheel

import terl_rt

pytestmark = pytest.mark.slow
CHECKS = Path(__file__).parent / "data" / "wheel_check"


@pytest.fixture(scope="module")
def fresh(tmp_path_factory) -> dict[str, Path]:
    """The wheel, and a fresh venv with it and its pettingzoo extra installed, plus mypy."""
    folder = tmp_path_factory.mktemp("fresh")
    wheel = build_wheel(folder)
    venv.create(folder / "venv", with_pip=True)
    python = folder / "venv" / "bin" / "python"
    install = subprocess.run(
        [python, "-m", "pip", "install", "-q", f"{wheel}[pettingzoo]", "mypy"], capture_output=True, text=True,
    )
    assert install.returncode == 0, install.stderr[-2000:]
    elsewhere = folder / "elsewhere"
    elsewhere.mkdir()
    return {"wheel": wheel, "python": python, "bin": python.parent, "cwd": elsewhere}


def run(fresh, *command) -> subprocess.CompletedProcess:
    done = subprocess.run([str(part) for part in command], cwd=fresh["cwd"], capture_output=True, text=True)
    assert done.returncode == 0, f"{command}: {done.stdout[-1000:]}{done.stderr[-2000:]}"
    return done


def test_the_installed_package_is_the_wheel_not_the_checkout(fresh):
    where = run(fresh, fresh["python"], "-c", "import terl_rt; print(terl_rt.__file__)").stdout.strip()
    assert Path(where).is_relative_to(fresh["python"].parents[1]), where


def test_python_m_terl_rt_version(fresh):
    assert run(fresh, fresh["python"], "-m", "terl_rt", "--version").stdout.strip() == f"terl-rt, version {terl_rt.__version__}"


def test_terl_rt_eval_runs_the_shipped_policy(fresh):
    out = run(fresh, fresh["bin"] / "terl-rt", "eval", "--episodes", "2", "--json").stdout
    result = json.loads(out)
    assert result["scenarios"][0]["name"] == "small-15" and result["scenarios"][0]["episodes"] == 2


def test_an_eval_log_holds_world_as_foxglove_s_protobuf_scene_update(fresh):
    log = fresh["cwd"] / "run.mcap"
    run(fresh, fresh["bin"] / "terl-rt", "eval", "--episodes", "1", "--max-steps", "20", "--log", log, "--force")
    assert "/world messages are foxglove.SceneUpdate" in run(fresh, fresh["python"], CHECKS / "world_protobuf.py", log).stdout


def test_pettingzoo_s_own_tests_pass(fresh):
    assert "passed" in run(fresh, fresh["python"], CHECKS / "pettingzoo_tests.py").stdout


def test_mypy_checks_a_user_script_against_the_package(fresh):
    mypy = [fresh["python"], "-m", "mypy", "--no-incremental", "--strict"]
    run(fresh, *mypy, CHECKS / "user_script.py")
    wrong = subprocess.run([str(p) for p in [*mypy, CHECKS / "wrong_script.py"]], cwd=fresh["cwd"], capture_output=True, text=True)
    assert wrong.returncode == 1, wrong.stdout
    assert 'expression has type "int", variable has type "str"' in wrong.stdout, wrong.stdout


def test_the_wheel_carries_license_and_citation(fresh):
    with zipfile.ZipFile(fresh["wheel"]) as archive:
        names = archive.namelist()
    assert any(name.endswith(".dist-info/licenses/LICENSE") for name in names)
    assert any(name.endswith(".dist-info/licenses/CITATION.cff") for name in names)
    assert "terl_rt/py.typed" in names
