"""The local backend: batches of episodes in this process (one worker) or in worker processes (POSIX).

The specs run in batches (terl_rt.evaluation.runs.batches), each batch's episodes together
in one World. With `workers > 1` the batches are spread over worker processes
(terl_rt.evaluation.worker), each started in a session of its own, so that a terminal's
Ctrl-C or hang-up reaches this process alone, however early it comes: this process
decides and tells the workers. Each worker gets the policies as the bytes this process
read (a file replaced during the run is never read again) and a batch at a time over its
own socket, on which it sends each step as it takes it; this process delivers them to the
run (terl_rt.evaluation.runs). Stopped (Ctrl-C, SIGTERM, SIGHUP) or failed, the workers
stop within a step and what they sent is delivered. A worker that dies is noticed at once
(its socket closes) and ends the run with a BackendError. No wait on a worker is without
a bound: one that does not end when told is killed. Workers end with their parent, even
when it is killed (SIGKILL).
"""

from __future__ import annotations

import signal
import subprocess
import time
from collections import deque
from collections.abc import Sequence
from multiprocessing import Pipe
from multiprocessing.connection import wait
from typing import Any

from terl_rt.evaluation import worker
from terl_rt.evaluation.play import BATCH_ENVS, batch_steps, check_envs
from terl_rt.evaluation.runs import (
    BackendError,
    Deliver,
    EpisodeSpec,
    Stopped,
    batches,
    raise_stop,
    stop_signals_as_flag,
)
from terl_rt.policy.onnx_policy import OnnxPolicy


class LocalBackend:
    """Runs batches of episodes on this machine: in this process when `workers` is 1, else
    in that many worker processes. threads: onnxruntime intra-op threads of each worker's
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
                for kind, j, payload in batch_steps(policies[spec.policy], spec.scenario, seeds, record, self.envs,
                                                    acting=spec.acting):
                    deliver(kind, batch[j], payload)
            return
        _run_in_workers(policies, specs, parts, min(self.workers, len(parts)), self.threads, self.envs, record,
                        deliver)


DRAIN_S = 10.0
"""s: how long a stopped run waits for its workers to send the steps they still take (one each)."""
END_S = 5.0
"""s: how long the workers have to end once their socket is closed, before they are killed."""


class _Worker:
    """One worker process and this process's end of its socket."""

    def __init__(self, number: int):
        self.number = number
        self.connection, theirs = Pipe(duplex=True)
        try:
            self.process = subprocess.Popen(worker.command(theirs.fileno()), pass_fds=(theirs.fileno(),),
                                            start_new_session=True, stdin=subprocess.DEVNULL)
        except BaseException:
            self.connection.close()
            raise
        finally:
            theirs.close()  # the worker's alone now: when it ends, the socket reads as closed
        self.busy = False
        """a task was sent and its "idle" (or "error") has not come back."""
        self.heard = False
        """a message has come from it (it has run)."""

    def send_policies(self, models: tuple[tuple[str, bytes], ...], threads: int) -> None:
        """The run's policies, (path, ONNX bytes) each, and onnxruntime's threads for them."""
        self._send((models, threads))

    def give(self, task: tuple | None) -> None:
        """A batch to run (see terl_rt.evaluation.worker), or None: there is none left."""
        self._send(task)
        self.busy = task is not None

    def tell_to_stop(self) -> None:
        """Stop at the next step (any message does), then end; nothing when it has gone."""
        try:
            self.connection.send(None)
        except OSError:
            pass

    def _send(self, message) -> None:
        try:
            self.connection.send(message)
        except OSError:
            raise BackendError(self.death()) from None

    def receive(self) -> tuple:
        """The next message; a BackendError naming the worker when it has died."""
        try:
            message = self.connection.recv()
        except (EOFError, OSError):
            raise BackendError(self.death()) from None
        self.heard = True
        if message[0] in ("idle", "error"):
            self.busy = False
        return message

    def death(self) -> str:
        """What ended the run when the worker's socket closed: its pid and how it ended."""
        try:
            status = self.process.wait(timeout=END_S)
        except subprocess.TimeoutExpired:
            status = None
        how = ("it did not end" if status is None else f"killed by {_signal_name(-status)}" if status < 0
               else f"exit status {status}")
        return (f"worker {self.number} (pid {self.process.pid}) ended unexpectedly ({how}; a kill, or too "
                "little memory); the episodes it ran are not complete, the steps it sent are kept")

    def end(self, deadline: float) -> None:
        """Wait for the worker to end once its socket is closed; kill it when it has not ended
        by `deadline` (time.monotonic()) or has never been heard from (it holds nothing sent)."""
        try:
            self.process.wait(timeout=max(0.0, deadline - time.monotonic()) if self.heard else 0.0)
        except subprocess.TimeoutExpired:
            self.process.kill()
            try:
                self.process.wait(timeout=END_S)
            except subprocess.TimeoutExpired:  # not reaped yet: subprocess reaps it later
                pass


def _signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


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
    """Run the batches `parts` of the specs in `workers` worker processes, a batch at a time
    each, in the order of `parts`, delivering their messages as they arrive."""
    models = tuple((str(policy.path), policy.model) for policy in policies)
    todo = deque(
        (batch, specs[batch[0]].policy, specs[batch[0]].scenario, [specs[number].seed for number in batch], envs,
         record, specs[batch[0]].acting)
        for batch in parts
    )
    started: list[_Worker] = []
    ended = 0
    # Installed before the first worker starts: a signal from now on only sets the flag.
    with stop_signals_as_flag() as received:
        try:
            for number in range(workers):
                started.append(_Worker(number + 1))
            for one in started:
                raise_stop(received)
                one.send_policies(models, 1 if threads is None else threads)
                one.give(todo.popleft())
            by_connection: dict[Any, _Worker] = {one.connection: one for one in started}
            while ended < len(specs):
                raise_stop(received)
                if not by_connection:  # never so: each batch ends its episodes; but no wait without end
                    raise BackendError(f"the workers ended with {len(specs) - ended} episodes not run")
                for connection in wait(list(by_connection), 0.1):
                    one = by_connection[connection]
                    kind, number, payload = one.receive()
                    if kind == "error":
                        raise payload
                    if kind == "idle":
                        one.give(todo.popleft() if todo else None)
                        if not one.busy:  # it ends now: its socket closing is no death
                            del by_connection[connection]
                    else:
                        ended += kind == "end"
                        deliver(kind, number, payload)
        except BaseException as error:
            # Stopped or failed: the workers stop within a step; what they send is delivered.
            for one in started:
                one.tell_to_stop()
            _drain([one for one in started if one.busy and one.heard], deliver)
            if isinstance(error, Stopped) or not received:
                raise
            # A stop asked for wins over what followed it (a worker the same Ctrl-C reached
            # in the instant before it left the terminal's process group).
            raise Stopped(received[0]) from None
        finally:
            for one in started:
                one.connection.close()  # each ends at once (between batches) or within a step
            deadline = time.monotonic() + END_S
            for one in started:
                one.end(deadline)


def _drain(busy: list[_Worker], deliver: Deliver) -> None:
    """Deliver what the `busy` workers still send until each has stopped (at most DRAIN_S)."""
    deadline = time.monotonic() + DRAIN_S
    waiting: dict[Any, _Worker] = {one.connection: one for one in busy}
    while waiting and time.monotonic() < deadline:
        for connection in wait(list(waiting), min(0.1, max(0.0, deadline - time.monotonic()))):
            one = waiting[connection]
            try:
                kind, number, payload = one.receive()
            except BackendError:  # it died meanwhile: the error that stopped the run goes on
                del waiting[connection]
                continue
            if kind in ("step", "end"):
                deliver(kind, number, payload)
            else:
                del waiting[connection]
