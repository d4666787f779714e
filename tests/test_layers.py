"""The parts of the repository point one way (docs/layout.md): import-linter's contracts in
pyproject.toml, checked as CI's `lint-imports` checks them."""

from __future__ import annotations

import logging
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]


def test_the_import_contracts_hold(monkeypatch, capsys):
    lint = pytest.importorskip("importlinter.cli", reason="needs import-linter: pip install -e '.[dev]'")
    # lint_imports configures logging with dictConfig, which disables every logger that exists
    # by then (the later tests' warnings would go silent): each comes back as it was.
    for logger in list(logging.Logger.manager.loggerDict.values()):
        if isinstance(logger, logging.Logger):
            monkeypatch.setattr(logger, "disabled", logger.disabled)
    monkeypatch.chdir(ROOT)
    status = lint.lint_imports(config_filename=str(ROOT / "pyproject.toml"), no_cache=True, no_logo=True)
    assert status == 0, capsys.readouterr().out


def test_the_simulator_takes_its_observation_layout_from_no_other_part():
    source = (ROOT / "terl_rt" / "sim" / "observation.py").read_text()
    assert "terl_rt.policy" not in source.replace("(terl_rt.policy.contract)", "")
    from terl_rt.policy import contract
    from terl_rt.sim import observation

    for name in ("EGO_FEATURES", "TEAMMATE_FEATURES", "EVADER_FEATURES", "OBSTACLE_FEATURES", "INPUT_NAMES"):
        assert getattr(contract, name) is getattr(observation, name), name
    assert tuple(spec.name for spec in contract.INPUTS) == observation.INPUT_NAMES


def names_in_layout(start: str, end: str) -> set[str]:
    """The words of docs/layout.md's package tree from the line that starts with `start` to
    the one that starts with `end`."""
    text = (ROOT / "docs" / "layout.md").read_text()
    begin = text.index("\n" + start) + 1
    return set(re.findall(r"[a-z_]+", text[begin : text.index("\n" + end, begin)]))


def test_the_layout_names_every_module_of_trainings_core_and_of_its_lab():
    def modules(folder: Path) -> set[str]:
        return {path.stem for path in folder.glob("*.py") if not path.stem.startswith("__")}

    assert modules(ROOT / "training") <= names_in_layout("training/ ", "  lab/ ")
    assert modules(ROOT / "training" / "lab") <= names_in_layout("  lab/ ", "  cli/ ")


def test_the_replay_buffer_takes_its_input_names_from_the_contract():
    source = (ROOT / "training" / "buffer.py").read_text()
    assert "training.export" not in source
    assert re.search(r"^from terl_rt\.policy\.contract import .*\bINPUT_NAMES\b", source, re.MULTILINE)


MODULE_LINES = 450
"""Rooms of one job (STYLE.md): past about this many lines a module usually holds two jobs."""


def test_no_module_of_the_runtime_is_over_450_lines():
    sizes = {
        str(path.relative_to(ROOT)): len(path.read_text().splitlines()) for path in (ROOT / "terl_rt").rglob("*.py")
    }
    over = {path: lines for path, lines in sizes.items() if lines > MODULE_LINES}
    assert over == {}, f"over {MODULE_LINES} lines: split each along the seam its own sections mark"
