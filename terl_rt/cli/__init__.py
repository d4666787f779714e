"""The terl-rt command line (click): a thin layer over the Python API."""

import sys  # loaded with the interpreter: importing it cannot be interrupted


def main() -> None:
    """The `terl-rt` command (its console script and `python -m terl_rt`).

    Loading the command's modules takes seconds on a busy machine: Ctrl-C meanwhile ends
    in one line and exit status 130 (128 + SIGINT), as it does later
    (terl_rt.cli.main.TerlGroup). Until then this package imports nothing the
    interpreter has not loaded.
    """
    try:
        from terl_rt.cli.main import cli
    except (KeyboardInterrupt, ImportError) as error:
        if not _caused_by_ctrl_c(error):
            raise
        _fail("stopped by SIGINT while starting", 130)
    cli(prog_name="terl-rt")


def _caused_by_ctrl_c(error: BaseException | None) -> bool:
    """True when `error` is a KeyboardInterrupt or one lies behind it (a compiled module,
    onnxruntime's among them, reports Ctrl-C during its initialisation as an ImportError)."""
    while error is not None:
        if isinstance(error, KeyboardInterrupt):
            return True
        error = error.__cause__ or error.__context__
    return False


def _fail(message: str, status: int) -> None:
    """One error line on stderr, then exit with `status`."""
    sys.stderr.write(f"Error: {message}\n")
    sys.exit(status)
