"""Speed of the simulator, of policies and of the evaluation backends, `terl-rt bench`
(timings are reported, never asserted in tests)."""

from __future__ import annotations

import math
import resource
import time
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import asdict, dataclass, field

import numpy as np

from terl_rt.evaluation.backends import open_backend
from terl_rt.evaluation.evaluate import evaluate_policy
from terl_rt.evaluation.optimize import record_observations
from terl_rt.evaluation.play import BATCH_ENVS
from terl_rt.policy.flops import MATMUL_GFLOPS, OnnxMissing, flops_per_row
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.actions import NUM_PURSUER_ACTIONS
from terl_rt.sim.rollout import Rollout
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.world import World

SCALING_PURSUERS = (15, 80, 200, 400)
"""Pursuer counts of the scaling table; evaders are a quarter of that."""


@dataclass(frozen=True)
class SimulatorSpeed:
    """Speed of World.step with random pursuer actions and the default (APF) evaders."""

    scenario: str
    pursuers: int
    evaders: int
    num_envs: int
    steps: int
    """timed steps of the batch (each advances num_envs environments)."""
    env_steps_per_s: float
    """environment steps per second (steps * num_envs / time)."""
    ms_per_step: float
    """milliseconds per batch step."""
    resets: int
    """episodes restarted during the run (their time is not counted)."""

    def to_dict(self) -> dict:
        return asdict(self)


SIM_WARMUP = 5
"""untimed batch steps before `simulator_speed` starts its clock."""


def simulator_speed(
    scenario: Scenario, steps: int, num_envs: int = 1, seed: int = 0, warmup: int = SIM_WARMUP,
    progress: Callable[[int], None] | None = None,
) -> SimulatorSpeed:
    """Time `steps` batch steps (after `warmup` untimed ones): the scatter of random actions
    of the active pursuers and World.step; finished episodes restart untimed.
    progress: called with 1 after every batch step, warm-up included (a progress bar's update)."""
    rollout = Rollout(World(scenario, num_envs=num_envs, seed=seed))
    rng = np.random.default_rng(seed)
    elapsed, resets = 0.0, 0
    for k in range(warmup + steps):
        turn = rollout.turn()
        resets += len(turn.restarted)
        chosen = rng.integers(0, NUM_PURSUER_ACTIONS, len(turn.rows))
        start = time.perf_counter()
        rollout.step(chosen)
        if k >= warmup:
            elapsed += time.perf_counter() - start
        if progress is not None:
            progress(1)
    return SimulatorSpeed(
        scenario=scenario.name,
        pursuers=scenario.pursuers,
        evaders=scenario.evaders,
        num_envs=num_envs,
        steps=steps,
        env_steps_per_s=steps * num_envs / elapsed,
        ms_per_step=1e3 * elapsed / steps,
        resets=resets,
    )


def scaling_scenario(pursuers: int) -> Scenario:
    """large-80's world grown to `pursuers` pursuers and a quarter as many evaders, the
    arena side scaled with sqrt(pursuers / 80) so that the robots' density stays put."""
    side = round(220.0 * math.sqrt(pursuers / 80.0))
    return Scenario.preset("large-80").replace(
        name=f"scale-{pursuers}", pursuers=pursuers, evaders=max(1, pursuers // 4), arena=(float(side), float(side))
    )


POLICY_BATCHES = (1, 80, 1600)
"""Rows a policy call is timed at: one robot's controller, every pursuer of a large-80 step,
and the pursuers of 20 large-80 episodes batched (terl_rt.evaluation.play.BATCH_ENVS)."""


@dataclass(frozen=True)
class PolicyLatency:
    """Latency of one policy call of `batch` rows (real observations), over `calls` calls."""

    policy: str
    scenario: str
    batch: int
    """rows of each call."""
    calls: int
    ms_p50: float
    ms_p99: float
    us_per_pursuer: float
    """microseconds per row at the median (ms_p50 / batch)."""
    mflop_per_row: float | None
    """MFLOP of matrix products a row (terl_rt.policy.flops); None without onnx."""
    gflops: float | None
    """GFLOP/s of matrix products at the median call."""
    matmul_share: float | None
    """gflops over MATMUL_GFLOPS, the machine's fp32 matrix-multiply rate."""

    def to_dict(self) -> dict:
        return asdict(self)


def policy_latencies(policy, scenario: Scenario, batches: Sequence[int] = POLICY_BATCHES, calls: int = 100,
                     seed: int = 0) -> list[PolicyLatency]:
    """Time `calls` policy calls at each batch size of `batches` (rows of the observations of
    `World(scenario, ceil(max(batches) / N), seed)` after reset), the sizes taken in turn so
    that a load that drifts meets them alike, one untimed call of each first; the FLOPs a row
    of each batch are counted where onnx is installed."""
    world = World(scenario, num_envs=math.ceil(max(batches) / scenario.pursuers), seed=seed)
    observation = world.reset()
    inputs = {batch: observation.rows(np.arange(batch)) for batch in batches}
    for batch in batches:  # the untimed calls, before the FLOP count: a policy that fails says so here
        policy.evaluate(inputs[batch])
    try:
        mflop = {batch: flops_per_row(policy, inputs[batch]) / 1e6 for batch in batches}
    except OnnxMissing:
        mflop = dict.fromkeys(batches)
    times: dict[int, list[float]] = {batch: [] for batch in batches}
    for _ in range(calls):
        for batch in batches:
            start = time.perf_counter()
            policy.evaluate(inputs[batch])
            times[batch].append(time.perf_counter() - start)
    rows = []
    for batch in batches:
        p50, p99 = (float(v) for v in 1e3 * np.percentile(times[batch], [50, 99]))
        gflops = None if mflop[batch] is None else mflop[batch] * batch / p50  # MFLOP / ms
        rows.append(PolicyLatency(
            policy=policy.name, scenario=scenario.name, batch=batch, calls=calls, ms_p50=p50, ms_p99=p99,
            us_per_pursuer=1e3 * p50 / batch, mflop_per_row=mflop[batch], gflops=gflops,
            matmul_share=None if gflops is None else gflops / MATMUL_GFLOPS,
        ))
    return rows


@dataclass(frozen=True)
class PoliciesSideBySide:
    """CPU time a row of several policy files on the same recorded rows of one scenario,
    called in turn (`policies_side_by_side`)."""

    scenario: str
    rows: int
    valid_tokens: float
    """share of the rows' tokens that are valid (not padding)."""
    policies: list[str]
    """the files, as given."""
    us_per_row: list[float]
    """CPU microseconds a row of each policy (this process, every thread), in calls as
    `OnnxPolicy.evaluate` makes them."""
    speedups: list[float]
    """the first policy's CPU time over each policy's."""
    same_outputs: list[bool]
    """each policy's q_values and target_weights equal the first policy's, bit for bit."""

    def to_dict(self) -> dict:
        return asdict(self)


def policies_side_by_side(policies: Sequence, scenario: Scenario, rounds: int = 6, seed: int = 0,
                          envs: int = 4, steps: int = 400, every: int = 20) -> PoliciesSideBySide:
    """Time `policies` on the rows that the first one meets in its own episodes (`envs`
    worlds of `scenario`, seed `seed`, every `every`-th of `steps` steps: rows of whole
    episodes, padding as evaluation meets it, not only of a reset), each policy called on
    all rows in turn, `rounds` times, after one untimed call each. CPU time (not wall
    clock) reads the work done even on a loaded machine."""
    (observation,) = record_observations(policies[0], [scenario], seed=seed, envs=envs, steps=steps, every=every)
    outputs = [policy.evaluate(observation) for policy in policies]
    spent = [0.0] * len(policies)
    for _ in range(rounds):
        for index, policy in enumerate(policies):
            start = time.process_time()
            policy.evaluate(observation)
            spent[index] += time.process_time() - start
    rows = len(observation.mask)
    return PoliciesSideBySide(
        scenario=scenario.name, rows=rows, valid_tokens=float(observation.mask.mean()),
        policies=[str(policy.path) for policy in policies],
        us_per_row=[1e6 * cpu / rounds / rows for cpu in spent],
        speedups=[spent[0] / cpu for cpu in spent],
        same_outputs=[
            all(np.array_equal(getattr(outputs[0], name), getattr(output, name)) for name in ("q_values", "target_weights"))
            for output in outputs
        ],
    )


@dataclass(frozen=True)
class BackendSpeed:
    """Time to evaluate a policy on scenarios with one backend, scenario by scenario as
    `terl-rt eval` and `terl-rt report` do."""

    backend: str
    workers: int
    episodes: int
    """episodes of one run, all scenarios."""
    start_s: float
    """s: opening the backend (starting a local Ray instance; nothing for local)."""
    run_s: float
    """s: the best of the runs (local worker processes start inside it, per scenario)."""
    episodes_per_s: float
    """episodes / run_s."""
    per_episode: tuple[EpisodeMetrics, ...] = field(repr=False)
    """every episode's metrics, scenario by scenario (to check that backends agree)."""
    envs: int = BATCH_ENVS
    """episodes a batch ran at once (1: each alone, one policy call a step for its pursuers)."""
    cpu_s: float = math.nan
    """s: CPU time of the best run, this process and the worker processes it waited for (a
    Ray backend's workers are not counted); less sensitive than run_s to a loaded machine."""

    def to_dict(self) -> dict:
        return {key: value for key, value in asdict(self).items() if key != "per_episode"}


def backend_speeds(policy, scenarios: Sequence[Scenario], episodes: int, seed: int, workers: int,
                   backends: Sequence[str] = ("local", "ray"), repeat: int = 1,
                   max_steps: int | None = None, envs: Sequence[int] = (BATCH_ENVS,)) -> list[BackendSpeed]:
    """Open each backend with `workers` workers for each batch size of `envs` (a Ray
    backend starts its own local instance), then evaluate `policy` on each scenario in turn
    (`episodes` each, episode k with seed + k) on one after the other, `repeat` rounds, so
    that a load that drifts meets them alike; each one's best round counts. Closing is not
    timed. Rows come backend by backend, batch sizes within."""
    runs = [(name, size) for name in backends for size in envs]
    with ExitStack() as stack:
        opened, start_s = {}, {}
        for run in runs:
            start = time.perf_counter()
            opened[run] = stack.enter_context(open_backend(run[0], workers, envs=run[1]))
            start_s[run] = time.perf_counter() - start
        best = dict.fromkeys(runs, (math.inf, math.nan))
        per_episode = {}
        for _ in range(repeat):
            for run in runs:
                start, cpu = time.perf_counter(), _cpu_s()
                results = [evaluate_policy(policy, scenario, episodes, seed, max_steps=max_steps, backend=opened[run])
                           for scenario in scenarios]
                best[run] = min(best[run], (time.perf_counter() - start, _cpu_s() - cpu))
                per_episode[run] = tuple(m for result in results for m in result.per_episode)
    total = episodes * len(scenarios)
    return [
        BackendSpeed(backend=run[0], workers=workers, episodes=total, start_s=start_s[run], run_s=best[run][0],
                     episodes_per_s=total / best[run][0], per_episode=per_episode[run], envs=run[1], cpu_s=best[run][1])
        for run in runs
    ]


def _cpu_s() -> float:
    """s: CPU time (user + system) of this process and of the children it has waited for."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


@dataclass(frozen=True)
class ActingCost:
    """CPU time per evaluation step of one acting rule (`acting_costs`)."""

    acting: str
    """the rule's label ("" for the greedy rule, the paper's)."""
    steps: int
    """timed batch steps (each advances every environment of the batch)."""
    decisions: int
    """pursuer-steps decided in them."""
    cpu_ms_per_step: float
    """ms of CPU time (this process) per batch step: policy, rule and simulator together."""
    ratio: float
    """cpu_ms_per_step over the first rule's."""

    def to_dict(self) -> dict:
        return asdict(self)


def acting_costs(policy, scenario: Scenario, actings: Sequence, steps: int = 50, envs: int = BATCH_ENVS,
                 seed: int = 0, repeat: int = 1) -> list[ActingCost]:
    """The CPU cost per evaluation step of each acting rule of `actings`
    (terl_rt.safety.acting.Acting): `steps` batch steps of `envs` environments of `scenario`
    from `seed` (episodes that end restart), as `terl-rt eval` steps them, after SIM_WARMUP
    untimed ones; the rules take turns, `repeat` rounds, each one's least CPU time counts.
    The rules' episodes part ways once the shield acts, so their rows differ a little."""
    best = [math.inf] * len(actings)
    decided = [0] * len(actings)
    for _ in range(repeat):
        for k, acting in enumerate(actings):
            rollout = Rollout(World(scenario, num_envs=envs, seed=seed))
            decisions, cpu = 0, 0.0
            for step in range(SIM_WARMUP + steps):
                start = time.process_time()
                turn = rollout.turn()
                rollout.step(acting.act(policy, turn.observation.rows(turn.rows), scenario.params).actions)
                if step >= SIM_WARMUP:
                    cpu += time.process_time() - start
                    decisions += len(turn.rows)
            best[k], decided[k] = min(best[k], cpu), decisions
    return [
        ActingCost(acting=acting.label, steps=steps, decisions=decided[k], cpu_ms_per_step=1e3 * best[k] / steps,
                   ratio=best[k] / best[0])
        for k, acting in enumerate(actings)
    ]
