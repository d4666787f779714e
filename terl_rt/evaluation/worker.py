"""A worker process of a `--workers` run: the side of terl_rt.evaluation.pool that runs batches.

The parent starts it with `command` (a new session: a terminal's Ctrl-C or hang-up never
reaches it, from its first instruction on) and talks to it over one socket, whose end
it gets as a file descriptor. What goes over it, each message pickled:

- parent -> worker: first `(models, threads)`, the policies of the run as (path, ONNX
  bytes) and onnxruntime's threads; then one task at a time, `(numbers, policy, scenario,
  seeds, envs, record, acting)`, or None: stop.
- worker -> parent: ("step", number, StepRecord) and ("end", number, EpisodeMetrics) as
  the batch takes them, ("idle", None, None) when it is done, or ("error", None, exception)
  when it failed (then it stops).

Any message from the parent during a batch is asked before every step and stops the batch
there (the parent sends one only to stop the run); so does the socket closing, when the
parent has gone. The worker also ends with its parent when that is killed (SIGKILL).
"""

from __future__ import annotations

import ctypes
import os
import pickle
import signal
import sys
import threading
import time
from multiprocessing.connection import Connection

from terl_rt.evaluation.play import batch_steps
from terl_rt.evaluation.runs import BackendError
from terl_rt.policy.onnx_policy import OnnxPolicy

_BOOT = "import sys; sys.path[:] = sys.argv[3:]; from terl_rt.evaluation.worker import main; main(sys.argv[1:3])"
"""The worker's program: the parent's module path first (this checkout's terl_rt), then `main`."""


def command(fd: int) -> list[str]:
    """The command line of a worker that talks on file descriptor `fd` to this process."""
    return [sys.executable, "-c", _BOOT, str(fd), str(os.getpid()), *sys.path]


def main(argv: list[str]) -> None:
    """`serve` the file descriptor and parent pid of `argv`, then end at once: everything was
    sent synchronously, and nothing else is left to tear down."""
    serve(int(argv[0]), int(argv[1]))
    os._exit(0)


def serve(fd: int, parent: int) -> None:
    """Run the tasks the parent (pid `parent`) sends on `fd` until it says stop or goes away."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent alone stops a run
    _die_with_parent(parent)
    connection = Connection(fd)
    try:
        models, threads = connection.recv()
        policies = [OnnxPolicy(path, threads=threads, model=model) for path, model in models]
        while (task := connection.recv()) is not None:
            numbers, policy, scenario, seeds, envs, record, acting = task
            for kind, j, payload in batch_steps(policies[policy], scenario, seeds, record, envs, connection.poll,
                                                acting):
                connection.send((kind, numbers[j], payload))
            connection.send(("idle", None, None))
    except (EOFError, BrokenPipeError, ConnectionResetError):
        return  # the parent has gone or closed the socket: nothing is waiting for more
    except Exception as error:  # the batch's own error (e.g. PolicyOutputError) goes to the parent
        _send_error(connection, error)


def _send_error(connection: Connection, error: Exception) -> None:
    """Send ("error", None, error); as a BackendError naming it when it cannot be pickled."""
    try:
        pickle.dumps(error)
    except Exception:
        error = BackendError(f"a worker failed: {type(error).__name__}: {error}")
    try:
        connection.send(("error", None, error))
    except OSError:
        pass  # the parent has gone


_PR_SET_PDEATHSIG = 1
_WATCHDOG_S = 0.5
"""s: how often a worker checks that its parent is still alive."""


def _die_with_parent(parent: int) -> None:
    """End this worker when its parent process (pid `parent`, the evaluating process) dies,
    even by SIGKILL: the kernel's parent-death signal where there is one (Linux), and a
    watchdog thread everywhere. A parent that died while the worker started ends it at once."""
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):  # no prctl: the watchdog alone
            pass
    if os.getppid() != parent:  # the parent died before the signal was armed
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(_WATCHDOG_S)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="terl-parent-watchdog", daemon=True).start()
