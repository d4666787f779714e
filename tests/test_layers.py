"""The parts of the repository point one way (docs/layout.md): import-linter's contracts in
pyproject.toml, checked as CI's `lint-imports` checks them."""

from __future__ import annotations

import logging
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
