"""What importing a part of terl_rt loads: the simulator needs NumPy alone."""

from __future__ import annotations

import subprocess
import sys

HEAVY = ("mcap", "onnxruntime", "torch")
"""Packages the simulator must not pull in (logs, policies and training need them)."""


def heavy_modules_after(code: str) -> list[str]:
    """The HEAVY packages in sys.modules after `code` runs in a fresh interpreter."""
    probe = f"{code}\nimport sys\nprint(*[name for name in {HEAVY!r} if name in sys.modules])"
    return subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout.split()


def test_the_simulator_imports_without_onnxruntime_mcap_or_torch():
    every_sim_module = (
        "import importlib, pkgutil, terl_rt.sim\n"
        "for module in pkgutil.iter_modules(terl_rt.sim.__path__):\n"
        "    importlib.import_module(f'terl_rt.sim.{module.name}')"
    )
    assert heavy_modules_after(every_sim_module) == []


def test_the_package_and_the_policy_contract_import_without_them():
    assert heavy_modules_after("import terl_rt, terl_rt.policy.contract") == []


def test_logs_and_policies_load_what_they_need():
    assert heavy_modules_after("import terl_rt.logs.reader, terl_rt.policy.onnx_policy") == ["mcap", "onnxruntime"]


def test_an_evaluation_on_the_command_line_loads_no_scipy():
    """scipy brings a second OpenBLAS, which aborts or never returns under a memory limit
    (issue 55); the success rate's exact interval needs none of it."""
    evaluation = (
        "from click.testing import CliRunner\n"
        "from terl_rt.cli.main import cli\n"
        "result = CliRunner().invoke(cli, ['eval', '--episodes', '2', '--max-steps', '5'])\n"
        "assert result.exit_code == 0, result.output\n"
        "import sys\n"
        "print('scipy' in sys.modules)"
    )
    loaded = subprocess.run([sys.executable, "-c", evaluation], capture_output=True, text=True, check=True).stdout
    assert loaded.split()[-1] == "False"


def test_training_help_answers_without_torch():
    """`python -m training --help` and every subcommand's: what trains, exports or loads a
    network is imported inside the command that does it (training/cli/__init__.py)."""
    every_help = (
        "import contextlib, io\n"
        "from training.cli.main import cli, main\n"
        "for name in ['', *cli.commands]:\n"
        "    with contextlib.redirect_stdout(io.StringIO()) as text:\n"
        "        assert main([name, '--help'] if name else ['--help']) == 0\n"
        "    assert 'Usage: python -m training' in text.getvalue()\n"
    )
    assert "torch" not in heavy_modules_after(every_help)
