"""The Ray backend: every episode a Ray task, on a local Ray instance or a cluster.

This module imports Ray; only `terl_rt.evaluation.backends.open_backend` imports it, when
the Ray backend is asked for, so terl_rt runs without Ray installed.

- Policies travel through Ray's object store (`ray.put` of the ONNX bytes), so workers
  need no shared filesystem; each worker process opens a policy once and keeps it.
- An episode is a streaming generator task: it yields each StepRecord as it takes it
  (only when the run is logged) and then its metrics; the driver takes them as they come
  and hands them to the run (terl_rt.evaluation.runs), which writes the log in order.
- A worker that dies (killed, its node lost) is retried on another by Ray
  (`EPISODE_RETRIES`). Ray reports a generator's items once each, by position: the retry
  runs the episode again from its seed and only its items past those already received
  come through, so no step or episode is counted twice, and since an episode is the same
  bit for bit wherever it runs, the stream joins up exactly. An exception inside an
  episode (a policy that outputs NaN) fails the same way again and is not retried.
- At most `workers` episodes are submitted at a time, in spec order, so that the steps the
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

from terl_rt.evaluation.play import episode_steps
from terl_rt.evaluation.runs import BackendError, Deliver, EpisodeSpec, sigint_as_flag
from terl_rt.policy.onnx_policy import OnnxPolicy
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.scenario import Scenario

EPISODE_RETRIES = 3
"""times Ray runs an episode again after its worker died."""
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


def episode_task(policy: _PolicyRef, scenario: Scenario, seed: int, record: bool):
    """One episode as a Ray generator task: its StepRecords (when `record`), then its EpisodeMetrics."""
    metrics = yield from episode_steps(_worker_policy(policy), scenario, seed, record)
    yield metrics


class RayBackend:
    """Runs episodes as Ray tasks.

    address: a running cluster to join (`HOST:PORT` of its head, or `auto`); None starts
    a local Ray instance with workers x threads CPUs (default: every CPU of this machine),
    shut down again by `close`. A process that has already called `ray.init` keeps its
    connection (and it stays open). workers: episodes run at once (default: as many as the
    cluster's CPUs hold); threads: onnxruntime intra-op threads of each episode's policy,
    and the CPUs each task asks Ray for (default 1). Raises BackendError when the cluster
    cannot be reached.
    """

    def __init__(self, address: str | None = None, workers: int | None = None, threads: int | None = None):
        if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
            raise ValueError(f"workers must be a positive integer or None, got {workers!r}")
        self.threads = 1 if threads is None else threads
        self._started = not ray.is_initialized()
        if self._started:
            _connect(address, None if workers is None else workers * self.threads)
        self.workers = workers or max(1, int(ray.cluster_resources().get("CPU", 1)) // self.threads)
        self._models: dict[str, ray.ObjectRef] = {}
        self._task = ray.remote(episode_task).options(
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
        waiting = iter(enumerate(specs))
        streams: dict = {}
        """ObjectRefGenerator -> spec number, of the episodes submitted and not yet ended."""

        def submit() -> None:
            for number, spec in itertools.islice(waiting, self.workers - len(streams)):
                streams[self._task.remote(refs[spec.policy], spec.scenario, spec.seed, record)] = number

        with sigint_as_flag() as interrupted:
            try:
                submit()
                while streams:
                    if interrupted:
                        raise KeyboardInterrupt
                    ready, _ = ray.wait(list(streams), num_returns=1, timeout=_WAIT_S)
                    for stream in ready:
                        _take(stream, streams, specs, deliver)
                    submit()
            except BaseException:
                # Interrupted or failed: the episodes stop; what they sent is delivered.
                for stream in streams:
                    ray.cancel(stream)
                _drain(streams, specs, deliver)
                raise

    def _policy_ref(self, policy: OnnxPolicy) -> _PolicyRef:
        if policy.sha256 not in self._models:
            self._models[policy.sha256] = ray.put(policy.model)
        return _PolicyRef(str(policy.path), policy.sha256, self.threads, self._models[policy.sha256])


def _take(stream, streams: dict, specs: Sequence[EpisodeSpec], deliver: Deliver) -> None:
    """Deliver the next item of a ready stream; an ended episode leaves `streams`."""
    number = streams[stream]
    try:
        item = ray.get(next(stream))
    except RayTaskError as error:
        raise error.cause from None  # the episode's own exception, e.g. PolicyOutputError
    except RayError as error:
        spec = specs[number]
        raise BackendError(
            f"episode {spec.index} of {spec.scenario.name} (seed {spec.seed}) could not be run on Ray: "
            f"{type(error).__name__}: {error}"
        ) from error
    if isinstance(item, EpisodeMetrics):
        del streams[stream]
        deliver("end", number, item)
    else:
        deliver("step", number, item)


def _drain(streams: dict, specs: Sequence[EpisodeSpec], deliver: Deliver) -> None:
    """Deliver every item the cancelled episodes had already sent."""
    for stream in list(streams):
        while stream in streams and ray.wait([stream], timeout=0)[0]:
            try:
                _take(stream, streams, specs, deliver)
            except Exception:  # the episode failed or was cancelled: the error that stopped the run goes on
                break


def _connect(address: str | None, cpus: int | None) -> None:
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
