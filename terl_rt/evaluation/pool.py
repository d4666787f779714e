"""The local backend: batches of episodes in this process (one worker) or in spawned processes.

The specs run in batches (terl_rt.evaluation.runs.batches), each batch's episodes together
in one World. With `workers > 1` the batches are spread over processes (spawn), each
reopening the policy files; they send each step to this process as they take it (one
pipe, one message at a time), which delivers it to the run (terl_rt.evaluation.runs).
Interrupted or failed, the workers stop within a step and what they sent is delivered.
Workers end with their parent, even when it is killed (SIGKILL).
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
from multiprocessing import get_context

from terl_rt.evaluation.play import BATCH_ENVS, batch_steps, check_envs
from terl_rt.evaluation.runs import Deliver, EpisodeSpec, batches, sigint_as_flag
from terl_rt.policy.onnx_policy import ContractError, OnnxPolicy
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
_worker_channel = None
"""(connection, lock): the pipe end every worker sends on, one message at a time."""

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


def _init_worker(files: tuple[tuple[str, str], ...], threads: int | None, stop, channel, parent: int) -> None:
    """files: (path, sha256) of every policy of the run, in order."""
    global _worker_policies, _worker_stop, _worker_channel
    # Ctrl-C reaches the whole process group: the parent handles it and sets `stop`,
    # which the workers check every step (killing them could leave a result half sent).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _die_with_parent(parent)
    _worker_stop = stop
    _worker_channel = channel
    _worker_policies = [OnnxPolicy(path, threads=threads) for path, _ in files]
    for policy, (path, sha256) in zip(_worker_policies, files):
        if policy.sha256 != sha256:
            raise ContractError(f"{path}: the policy file changed on disk during the evaluation")


def _worker_batch(numbers: list[int], policy: int, scenario: Scenario, seeds: list[int], envs: int,
                  record: bool) -> None:
    """Run the batch of specs `numbers` (seeds `seeds`, `envs` at once), sending ("step", number, StepRecord)
    for every step (when `record`) and ("end", number, metrics) to the parent as they happen."""
    for kind, j, payload in batch_steps(_worker_policies[policy], scenario, seeds, record, envs, _worker_stop.is_set):
        _send((kind, numbers[j], payload))


def _send(message: tuple) -> None:
    # Sent synchronously (no feeder thread): when the episode's future is done, every
    # message it sent is in the pipe, and a worker never exits with a message unsent.
    connection, lock = _worker_channel
    with lock:
        connection.send(message)


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
    messages to this one."""
    context = get_context("spawn")
    stop = context.Event()
    messages, sending = context.Pipe(duplex=False)
    files = tuple((str(policy.path), policy.sha256) for policy in policies)
    init = (files, 1 if threads is None else threads, stop, (sending, context.Lock()), os.getpid())
    pool = ProcessPoolExecutor(workers, mp_context=context, initializer=_init_worker, initargs=init)
    futures = []
    ended = 0
    with sigint_as_flag() as interrupted:
        try:
            futures = [
                pool.submit(_worker_batch, batch, specs[batch[0]].policy, specs[batch[0]].scenario,
                            [specs[number].seed for number in batch], envs, record)
                for batch in parts
            ]
            while ended < len(specs):
                if interrupted:
                    raise KeyboardInterrupt
                if messages.poll(0.1):
                    kind, number, payload = messages.recv()
                    ended += kind == "end"
                    deliver(kind, number, payload)
                else:
                    for future in futures:
                        if future.done() and future.exception() is not None:
                            raise future.exception()
            pool.shutdown()
        except BaseException:
            # Interrupted or failed: the workers stop within a step; what they sent is delivered.
            stop.set()
            for future in futures:
                future.cancel()
            try:
                _drain(messages, futures, deliver)
            finally:
                pool.shutdown(wait=True, cancel_futures=True)
            raise
        finally:
            messages.close()
            sending.close()


def _drain(messages, futures, deliver: Deliver, limit_s: float = 10.0) -> None:
    """Deliver what the workers still send until each has stopped (at most `limit_s`)."""
    deadline = time.monotonic() + limit_s
    while time.monotonic() < deadline:
        if messages.poll(0.05):
            deliver(*messages.recv())
        elif all(future.done() for future in futures):
            return
