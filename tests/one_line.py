"""Driving the terl-rt command through click's runner, and the one-line error it must end with."""

from __future__ import annotations

from click.testing import CliRunner

from terl_rt.cli.main import cli


def invoke(*args):
    """`terl-rt ARGS` (each turned to str) through click's runner."""
    return CliRunner().invoke(cli, [str(arg) for arg in args])


def assert_one_error(result, *words) -> None:
    """Exit status 2 and one `Error:` line, the last on stderr (a progress bar may come
    before it), holding each of `words`; no traceback."""
    assert result.exit_code == 2, result.output
    errors = [line for line in result.stderr.splitlines() if line.startswith("Error: ")]
    assert len(errors) == 1 and result.stderr.endswith(errors[0] + "\n"), result.stderr
    for word in words:
        assert word in errors[0], errors[0]
    assert "Traceback" not in result.output and (result.exception is None or isinstance(result.exception, SystemExit))
