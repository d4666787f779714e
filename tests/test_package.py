"""terl-rt as an installed package: it stands alone, away from the checkout."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from wheels import build_wheel

import terl_rt
from terl_rt import Scenario
from terl_rt.policy.shipped import packaged_policy_path

ROOT = Path(__file__).resolve().parents[1]


def test_the_packaged_default_policy_is_the_exported_one():
    """One policy, two places: exported/ (what users see) and the package (what installs)."""
    packaged = packaged_policy_path()
    assert packaged is not None
    assert packaged.read_bytes() == (ROOT / "exported" / "terl.onnx").read_bytes()
    assert packaged.with_suffix(".md").read_bytes() == (ROOT / "exported" / "terl.md").read_bytes()


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """The wheel of this checkout installed (not editable) into a folder of its own."""
    folder = tmp_path_factory.mktemp("wheel")
    try:
        wheel = build_wheel(folder)
    except RuntimeError as error:
        pytest.skip(f"cannot build a wheel here: {error}")
    target = folder / "site"
    with zipfile.ZipFile(wheel) as archive:
        archive.extractall(target)
    return target


def test_the_wheel_holds_the_runtime_and_its_policy_but_no_training_module(installed):
    top_level = {path.name for path in installed.iterdir() if not path.name.endswith(".dist-info")}
    assert top_level == {"terl_rt"}, top_level
    assert (installed / "terl_rt" / "policy" / "default" / "terl.onnx").is_file()
    assert (installed / "terl_rt" / "policy" / "default" / "terl.md").is_file()


def test_the_wheel_carries_the_license_citation_type_marker_and_foxglove_layout(installed):
    info = next(installed.glob("terl_rt-*.dist-info"))
    licenses = {path.name for path in (info / "licenses").iterdir()}
    assert licenses == {"LICENSE", "CITATION.cff"}, licenses
    assert (installed / "terl_rt" / "py.typed").is_file()
    assert json.loads((installed / "terl_rt" / "logs" / "foxglove-layout.json").read_text())["configById"]


def test_the_wheel_metadata_names_version_urls_and_classifiers(installed):
    metadata = (next(installed.glob("terl_rt-*.dist-info")) / "METADATA").read_text()
    assert f"Version: {terl_rt.__version__}" in metadata
    for field in ("Author: the terl-rt developers", "Project-URL: Paper, https://arxiv.org/abs/2503.12395",
                  "Classifier: Typing :: Typed", "Keywords:", "License-Expression: MIT"):
        assert field in metadata, field


def test_python_m_terl_rt_prints_the_version():
    run = subprocess.run([sys.executable, "-m", "terl_rt", "--version"], cwd=ROOT, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == f"terl-rt, version {terl_rt.__version__}"


def test_citation_cff_cites_the_paper_and_matches_the_version():
    text = (ROOT / "CITATION.cff").read_text()
    assert f"version: {terl_rt.__version__}" in text
    assert "arXiv:2503.12395" in text and "preferred-citation:" in text


def test_the_installed_terl_rt_evaluates_from_another_folder(installed, tmp_path):
    code = (
        "import sys, terl_rt; from terl_rt.cli.main import cli\n"
        "print('from', terl_rt.__file__, file=sys.stderr)\n"
        "cli(['eval', '--episodes', '1', '--max-steps', '5', '--scenario', 'small-11', '--json'])"
    )
    env = {**os.environ, "PYTHONPATH": str(installed)}
    run = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert f"from {installed}" in run.stderr  # the installed copy, not the checkout
    result = json.loads(run.stdout)
    assert Path(result["policy"]["path"]).is_relative_to(installed)
    assert result["scenarios"][0]["name"] == Scenario.preset("small-11").name


def test_the_docs_the_code_cites_are_in_the_repository():
    for name in ("world.md", "policy.md"):
        assert (ROOT / "docs" / name).is_file()
    for path in [ROOT / "README.md", *(ROOT / "docs").glob("*.md"), *(ROOT / "terl_rt").rglob("*.py")]:
        assert "shared/spec" not in path.read_text(), path


def test_the_scenario_file_example_of_world_md_loads(tmp_path):
    text = (ROOT / "docs" / "world.md").read_text()
    example = text.split("## 12. Scenario files")[1].split("```json")[1].split("```")[0]
    path = tmp_path / "world.json"
    path.write_text(example)
    scenario = Scenario.from_file(path)
    assert scenario.name == "my-world" and scenario.pursuers == 3
