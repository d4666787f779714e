"""The terl-rt command line (click): a thin layer over the Python API."""

import sys  # loaded with the interpreter: importing it cannot be interrupted

MIN_ADDRESS_SPACE = 256 << 20
"""Bytes of address space (`ulimit -v`) the command needs to load its modules, NumPy's
BLAS buffer and a policy (about 215 MiB on Linux x86-64): under a lower limit it stops
before loading them."""


def main() -> None:
    """The `terl-rt` command (its console script and `python -m terl_rt`).

    Loading the command's modules takes seconds on a busy machine: Ctrl-C meanwhile ends
    in one line and exit status 130 (128 + SIGINT), as it does later
    (terl_rt.cli.main.TerlGroup). Too little memory ends in one line and exit status 2,
    never in an abort inside a library: an address-space limit below MIN_ADDRESS_SPACE
    is refused first, NumPy's BLAS runs one thread, and its buffer is mapped before
    anything else is allocated (`_map_blas_buffer`). Until then this package imports
    nothing the interpreter has not loaded. A closed stdout (`>&-`), where every command
    prints its results, ends in one line and exit status 2 before any work is done.
    """
    if sys.stdout is None:  # what Python makes of a closed file descriptor 1
        _fail("stdout is closed, and terl-rt prints its results there; redirect it to a file or /dev/null", 2)
    try:
        _check_address_space()
        import os

        # The simulator's matrix products are small; workers are the parallelism. Each
        # BLAS thread costs address space, and BLAS ends the process when it cannot map it.
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
        from terl_rt.cli.main import cli

        _map_blas_buffer()
    except (KeyboardInterrupt, ImportError) as error:
        if not _caused_by_ctrl_c(error):
            raise
        _fail("stopped by SIGINT while starting", 130)
    except MemoryError:
        _fail("not enough memory to start terl-rt", 2)
    cli(prog_name="terl-rt")


def _caused_by_ctrl_c(error: BaseException | None) -> bool:
    """True when `error` is a KeyboardInterrupt or one lies behind it (a compiled module,
    onnxruntime's among them, reports Ctrl-C during its initialisation as an ImportError)."""
    while error is not None:
        if isinstance(error, KeyboardInterrupt):
            return True
        error = error.__cause__ or error.__context__
    return False


def _check_address_space() -> None:
    """Stop in one line when `ulimit -v` is below MIN_ADDRESS_SPACE (not on Windows)."""
    try:
        import resource
    except ImportError:
        return
    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    if limit != resource.RLIM_INFINITY and limit < MIN_ADDRESS_SPACE:
        _fail(
            f"not enough memory to start terl-rt: its address space is limited to {limit >> 20} MiB "
            f"(ulimit -v), and it needs {MIN_ADDRESS_SPACE >> 20} MiB", 2,
        )


def _map_blas_buffer() -> None:
    """Run one small matrix product: OpenBLAS maps its work buffer (32 MiB) at the first
    one and ends the process, with no error Python can catch, when it cannot. Mapped now,
    the buffer is there for every later product (one thread), and a run that meets the
    limit fails in NumPy or onnxruntime instead, where the error is one line."""
    import numpy as np

    np.ones((2, 2)) @ np.ones((2, 2))


def _fail(message: str, status: int) -> None:
    """One error line on stderr (where it is open), then exit with `status`."""
    if sys.stderr is not None:
        sys.stderr.write(f"Error: {message}\n")
    sys.exit(status)
