"""The local backend: batches of episodes in this process (one worker) or in spawned processes.

The specs run in batches (terl_rt.evaluation.runs.batches), each batch's episodes together
in one World. With `workers > 1` the batches are spread over processes (spawn), each
opening the policies from the bytes this process read (a file replaced during the run is
never read again); they send each step to this process as they take it (a pipe per
worker), which delivers it to the run (terl_rt.evaluation.runs). Interrupted (Ctrl-C,
SIGTERM, SIGHUP) or failed, the workers stop within a step and what they sent is
delivered; a worker that dies is noticed (its pipe closes) and ends the run with a
BackendError. Workers end with their parent, even when it is killed (SIGKILL).
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
import threading
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from multiprocessing import get_context, resource_tracker
from multiprocessing.connection import wait

from terl_rt.evaluation.play import BATCH_ENVS, batch_steps, check_envs
from terl_rt.evaluation.runs import BackendError, Deliver, EpisodeSpec, batches, raise_stop, stop_signals_as_flag
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.sim.scenario import Scenario


class LocalBackend:
    """Runs batches of episodes on this machine: in this process when `workers` is 1, else
    in that many spawned processes. threads: onnxruntime intra-op threads of each worker's
    policies (default 1; with one worker the policies are used as they were opened).
    envs: episodes a batch runs at once (its World's environments; 1 runs them one by one)."""

    def __init__(self, workers: int = 1, threads: int | None = None, envs: int = BATCH_ENVS):
        if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
            raise ValueError(f"workers must be a positive integer, got {workers!r}")
        self.workers = workers
        self.threads = threads
        self.envs = check_envs(envs)

    def __enter__(self) -> LocalBackend:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Nothing to give back: each run starts and ends its own processes."""

    def run(self, policies: Sequence[OnnxPolicy], specs: Sequence[EpisodeSpec], record: bool,
            deliver: Deliver) -> None:
        parts = batches(specs, self.workers)
        if min(self.workers, len(parts)) == 1:
            for batch in parts:
                spec = specs[batch[0]]
                seeds = [specs[number].seed for number in batch]
                for kind, j, payload in batch_steps(policies[spec.policy], spec.scenario, seeds, record, self.envs):
                    deliver(kind, batch[j], payload)
            return
        _run_in_workers(policies, specs, parts, min(self.workers, len(parts)), self.threads, self.envs, record,
                        deliver)


# --- worker processes ------------------------------------------------------------------

_worker_policies: list[OnnxPolicy] = []
_worker_stop = None
"""a shared byte (no lock, which a killed worker could leave held): nonzero once the run stops."""
_worker_connection = None
"""this worker's own pipe end to the parent (a dead worker's pipe closes; none other is touched)."""

_PR_SET_PDEATHSIG = 1
_WATCHDOG_S = 0.5
"""s: how often a worker checks that its parent is still alive."""

_GROUP_SIGNALS = {getattr(signal, name) for name in ("SIGINT", "SIGHUP") if hasattr(signal, name)}
"""What a terminal sends the whole process group (Ctrl-C, closing it): the parent handles
them and sets `stop`, which the workers check every step (killed, a worker could leave a
message half sent). Blocked while the workers start, ignored by them once started."""


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


def _init_worker(models: tuple[tuple[str, bytes], ...], threads: int | None, stop, connections, claimed,
                 parent: int) -> None:
    """models: (path, ONNX bytes) of every policy of the run, in order; connections: one pipe end
    per worker, of which this worker takes the first not yet `claimed` (a shared counter)."""
    global _worker_policies, _worker_stop, _worker_connection
    for signum in _GROUP_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, _GROUP_SIGNALS)  # blocked by the parent while we started
    _die_with_parent(parent)
    with claimed.get_lock():
        mine = claimed.value
        claimed.value += 1
    _worker_connection = connections[mine]
    for number, connection in enumerate(connections):
        if number != mine:
            connection.close()
    _worker_stop = stop
    _worker_policies = [OnnxPolicy(path, threads=threads, model=model) for path, model in models]


def _worker_batch(numbers: list[int], policy: int, scenario: Scenario, seeds: list[int], envs: int,
                  record: bool) -> None:
    """Run the batch of specs `numbers` (seeds `seeds`, `envs` at once), sending ("step", number, StepRecord)
    for every step (when `record`) and ("end", number, metrics) to the parent as they happen."""
    for kind, j, payload in batch_steps(_worker_policies[policy], scenario, seeds, record, envs, _stopped):
        # Sent synchronously (no feeder thread): when the batch's future is done, every
        # message it sent is in the pipe, and a worker never exits with a message unsent.
        _worker_connection.send((kind, numbers[j], payload))


def _stopped() -> bool:
    """Whether the parent has stopped the run (checked by the batch every step)."""
    return bool(_worker_stop.value)


@contextmanager
def _group_signals_blocked():
    """Hold back SIGINT and SIGHUP in this thread inside the block: processes spawned there
    inherit them blocked until their initializer ignores them, so a Ctrl-C while they
    start reaches only this process (delivered when the block ends)."""
    if not hasattr(signal, "pthread_sigmask") or threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, _GROUP_SIGNALS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


WORKER_DIED = ("a worker process ended unexpectedly (killed, or out of memory); the episodes it ran are not "
               "complete, what was run before is kept")


def _run_in_workers(
    policies: Sequence[OnnxPolicy],
    specs: Sequence[EpisodeSpec],
    parts: list[list[int]],
    workers: int,
    threads: int | None,
    envs: int,
    record: bool,
    deliver: Deliver,
) -> None:
    """Run the batches `parts` of the specs in `workers` spawned processes that stream their
    messages to this one, each on its own pipe."""
    context = get_context("spawn")
    stop = context.RawValue(ctypes.c_bool, False)
    pipes = [context.Pipe(duplex=False) for _ in range(workers)]
    readers = [reader for reader, _ in pipes]
    models = tuple((str(policy.path), policy.model) for policy in policies)
    futures = []
    ended = 0
    with stop_signals_as_flag() as interrupted:
        pool = None
        try:
            with _group_signals_blocked():
                # multiprocessing's resource tracker (a process of the group too, started at the
                # first lock) must not die of the terminal's SIGHUP either: it keeps them blocked.
                resource_tracker.ensure_running()
                init = (models, 1 if threads is None else threads, stop, [sending for _, sending in pipes],
                        context.Value("i", 0), os.getpid())
                pool = ProcessPoolExecutor(workers, mp_context=context, initializer=_init_worker, initargs=init)
                # Each submit up to `workers` starts a process (spawn), which takes its pipe ends then.
                futures = [
                    pool.submit(_worker_batch, batch, specs[batch[0]].policy, specs[batch[0]].scenario,
                                [specs[number].seed for number in batch], envs, record)
                    for batch in parts
                ]
            for _, sending in pipes:
                sending.close()  # the workers hold them now: a dead worker's pipe reads as closed
            while ended < len(specs):
                raise_stop(interrupted)
                ready = wait(readers, 0.1)
                for reader in ready:
                    message = _receive(reader, readers)
                    if message is not None:
                        ended += message[0] == "end"
                        deliver(*message)
                if not ready:
                    _raise_failure(futures)
                if not readers:  # every worker's pipe closed with episodes left
                    raise BackendError(WORKER_DIED)
            pool.shutdown()
        except BaseException as error:
            # Interrupted or failed: the workers stop within a step; what they sent is delivered.
            stop.value = True
            for future in futures:
                future.cancel()
            try:
                _drain(readers, futures, deliver)
            finally:
                if pool is not None:
                    pool.shutdown(wait=True, cancel_futures=True)
            if isinstance(error, BrokenProcessPool):
                raise BackendError(WORKER_DIED) from None
            raise
        finally:
            for reader, sending in pipes:
                reader.close()
                sending.close()


def _receive(reader, readers: list) -> tuple | None:
    """The next message on `reader`, or None when its worker has gone (the pipe closed, maybe
    in the middle of a message, which is lost); then it leaves `readers`."""
    try:
        return reader.recv()
    except (EOFError, OSError):
        readers.remove(reader)
        return None


def _raise_failure(futures) -> None:
    """Raise the error of the first batch that failed: its own (e.g. PolicyOutputError), or
    a BackendError when a worker died."""
    for future in futures:
        if future.done() and not future.cancelled() and future.exception() is not None:
            if isinstance(future.exception(), BrokenProcessPool):
                raise BackendError(WORKER_DIED)
            raise future.exception()


def _drain(readers: list, futures, deliver: Deliver, limit_s: float = 10.0) -> None:
    """Deliver what the workers still send until each has stopped (at most `limit_s`)."""
    deadline = time.monotonic() + limit_s
    while readers and time.monotonic() < deadline:
        ready = wait(readers, 0.05)
        for reader in ready:
            message = _receive(reader, readers)
            if message is not None:
                deliver(*message)
        if not ready and all(future.done() for future in futures):
            return
