"""The Ray backend: every batch of episodes a Ray task, on a local Ray instance or a cluster.

This module imports Ray; only `terl_rt.evaluation.backends.open_backend` imports it, when
the Ray backend is asked for, so terl_rt runs without Ray installed.

- Policies travel through Ray's object store (`ray.put` of the ONNX bytes), so workers
  need no shared filesystem; each worker process opens a policy once and keeps it.
- A batch (terl_rt.evaluation.runs.batches: a preset's episodes split over the workers)
  is a streaming generator task running its episodes together in one World: it yields
  each episode's messages (terl_rt.evaluation.play.batch_steps) as it takes them, steps
  only when the run is logged; the driver takes them as they come and hands them to the
  run (terl_rt.evaluation.runs), which writes the log in order.
- A worker that dies (killed, its node lost) is retried on another by Ray
  (`EPISODE_RETRIES`). Ray reports a generator's items once each, by position: the retry
  runs the batch again from its seeds and only its items past those already received
  come through, so no step or episode is counted twice, and since a batch yields the
  same items in the same order wherever it runs, the stream joins up exactly. An
  exception inside a batch (a policy that outputs NaN) fails the same way again and is
  not retried.
- At most `workers` batches are submitted at a time, in spec order, so that the steps the
  driver holds back for episode order stay few.
"""

from __future__ import annotations

import itertools
import logging
import re
import socket
from collections.abc import Sequence
from dataclasses import dataclass

import ray
from ray.exceptions import RayError, RayTaskError

from terl_rt.evaluation.play import BATCH_ENVS, batch_steps, check_envs
from terl_rt.evaluation.runs import BackendError, Deliver, EpisodeSpec, batches, raise_stop, stop_signals_as_flag
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.safety.acting import Acting
from terl_rt.sim.scenario import Scenario

EPISODE_RETRIES = 3
"""times Ray runs a batch again after its worker died."""
CONNECT_TIMEOUT_S = 10.0
"""s: how long a cluster's address may take to answer before the run gives up."""
_WAIT_S = 0.1
"""s: longest wait for a message before Ctrl-C is checked again."""
_HOST_PORT = re.compile(r"^\[?(?P<host>[^\]\s/]+?)\]?:(?P<port>\d{1,5})$")
"""HOST:PORT (or [IPv6]:PORT) of a cluster's head."""


@dataclass(frozen=True)
class _PolicyRef:
    """What a worker needs to open a policy: its bytes in the object store (a reference
    inside an argument, which Ray passes as it is: a worker fetches the bytes only the first
    time it meets the policy)."""

    path: str
    """names the policy (in errors); the file itself is not read by workers."""
    sha256: str
    threads: int
    model: ray.ObjectRef


_worker_policies: dict[tuple[str, int], OnnxPolicy] = {}
"""(sha256, threads) -> the policy, opened once per worker process."""


def _worker_policy(ref: _PolicyRef) -> OnnxPolicy:
    key = (ref.sha256, ref.threads)
    if key not in _worker_policies:
        _worker_policies[key] = OnnxPolicy(ref.path, threads=ref.threads, model=ray.get(ref.model))
    return _worker_policies[key]


def batch_task(policy: _PolicyRef, scenario: Scenario, seeds: list[int], record: bool, envs: int, acting: Acting):
    """A batch of episodes as a Ray generator task: the messages of `batch_steps` (acting by
    `acting`), (kind, j, payload) with j the episode's index into `seeds`."""
    yield from batch_steps(_worker_policy(policy), scenario, seeds, record, envs, acting=acting)


class RayBackend:
    """Runs batches of episodes as Ray tasks.

    address: a running cluster to join (`HOST:PORT` of its head, or `auto`); None starts
    a local Ray instance with workers x threads CPUs (default: every CPU of this machine),
    shut down again by `close`. A process that has already called `ray.init` keeps its
    connection (and it stays open). workers: batches run at once (default: as many as the
    cluster's CPUs hold); envs: episodes a batch runs at once; threads: onnxruntime
    intra-op threads of each batch's policy,
    and the CPUs each task asks Ray for (default 1). Raises BackendError when the cluster
    cannot be reached.
    """

    def __init__(self, address: str | None = None, workers: int | None = None, threads: int | None = None,
                 envs: int = BATCH_ENVS):
        self.envs = check_envs(envs)
        if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
            raise ValueError(f"workers must be a positive integer or None, got {workers!r}")
        self.threads = 1 if threads is None else threads
        self._started = not ray.is_initialized()
        if self._started:
            connect(address, None if workers is None else workers * self.threads)
        self.workers = workers or max(1, int(ray.cluster_resources().get("CPU", 1)) // self.threads)
        self._models: dict[str, ray.ObjectRef] = {}
        self._task = ray.remote(batch_task).options(
            num_cpus=self.threads, max_retries=EPISODE_RETRIES, retry_exceptions=False,
        )

    def __enter__(self) -> RayBackend:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Leave the cluster; a local instance started here stops."""
        if self._started and ray.is_initialized():
            ray.shutdown()

    def run(self, policies: Sequence[OnnxPolicy], specs: Sequence[EpisodeSpec], record: bool,
            deliver: Deliver) -> None:
        refs = [self._policy_ref(policy) for policy in policies]
        waiting = iter(batches(specs, self.workers))
        streams: dict = {}
        """ObjectRefGenerator -> [spec numbers of its batch, episodes not yet ended], of the
        batches submitted and not yet ended."""

        def submit() -> None:
            for batch in itertools.islice(waiting, self.workers - len(streams)):
                spec = specs[batch[0]]
                seeds = [specs[number].seed for number in batch]
                task = self._task.remote(refs[spec.policy], spec.scenario, seeds, record, self.envs, spec.acting)
                streams[task] = [batch, len(batch)]

        # Installed after ray.init (in __init__), so that Ctrl-C, SIGTERM and SIGHUP reach
        # this flag rather than Ray's own handlers.
        with stop_signals_as_flag() as interrupted:
            try:
                submit()
                while streams:
                    raise_stop(interrupted)
                    ready, _ = ray.wait(list(streams), num_returns=1, timeout=_WAIT_S)
                    for stream in ready:
                        _take(stream, streams, specs, deliver)
                    submit()
            except BaseException:
                # Interrupted or failed: the batches stop; what they sent is delivered.
                for stream in streams:
                    ray.cancel(stream)
                _drain(streams, specs, deliver)
                raise

    def _policy_ref(self, policy: OnnxPolicy) -> _PolicyRef:
        if policy.sha256 not in self._models:
            self._models[policy.sha256] = ray.put(policy.model)
        return _PolicyRef(str(policy.path), policy.sha256, self.threads, self._models[policy.sha256])


def _take(stream, streams: dict, specs: Sequence[EpisodeSpec], deliver: Deliver) -> None:
    """Deliver the next item of a ready stream; a batch whose episodes all ended leaves `streams`."""
    batch, running = streams[stream]
    try:
        kind, j, payload = ray.get(next(stream))
    except RayTaskError as error:
        raise error.cause from None  # the batch's own exception, e.g. PolicyOutputError
    except RayError as error:
        spec, last = specs[batch[0]], specs[batch[-1]]
        raise BackendError(
            f"episodes {spec.index}-{last.index} of {spec.scenario.name} (seeds {spec.seed}-{last.seed}) could not "
            f"be run on Ray: {type(error).__name__}: {error}"
        ) from error
    deliver(kind, batch[j], payload)
    if kind == "end":
        streams[stream][1] = running - 1
        if running == 1:
            del streams[stream]


def _drain(streams: dict, specs: Sequence[EpisodeSpec], deliver: Deliver) -> None:
    """Deliver every item the cancelled batches had already sent."""
    for stream in list(streams):
        while stream in streams and ray.wait([stream], timeout=0)[0]:
            try:
                _take(stream, streams, specs, deliver)
            except Exception:  # the batch failed or was cancelled: the error that stopped the run goes on
                break


def connect(address: str | None, cpus: int | None) -> None:
    """ray.init: a new local instance with `cpus` CPUs (None: this machine's), or the cluster at `address`."""
    options = {"include_dashboard": False, "logging_level": logging.WARNING}
    if address is None:
        ray.init(address="local", num_cpus=cpus, **options)
        return
    match = _HOST_PORT.match(address)
    if match:
        # Ray waits for minutes on an address where nothing answers: ask first.
        try:
            socket.create_connection((match["host"], int(match["port"])), timeout=CONNECT_TIMEOUT_S).close()
        except OSError as error:
            raise BackendError(
                f"--address {address}: no Ray cluster answers there ({error.strerror or error}); "
                "start one with `ray start --head` and pass the address it prints"
            ) from None
    try:
        ray.init(address=address, **options)
    except (ConnectionError, ValueError, RuntimeError) as error:
        raise BackendError(f"--address {address}: {error}") from None
