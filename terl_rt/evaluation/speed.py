"""Speed of the simulator, of policies and of the evaluation backends, `terl-rt bench`
(timings are reported, never asserted in tests)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from dataclasses import asdict, dataclass, field

import numpy as np

from terl_rt.evaluation.backends import open_backend
from terl_rt.evaluation.episodes import evaluate_policy
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


@dataclass(frozen=True)
class PolicySpeed:
    """Time to choose the actions of all active pursuers: one policy call per step."""

    policy: str
    scenario: str
    pursuers: int
    steps: int
    """timed steps (policy calls)."""
    rows_mean: float
    """mean active pursuers per call (the batch the policy saw)."""
    ms_per_step: float
    """milliseconds per step: the policy's actions for every active pursuer, in one call."""
    ms_p50: float
    ms_p90: float
    us_per_pursuer: float
    """microseconds per pursuer row (ms_per_step / rows_mean)."""
    resets: int
    """episodes restarted during the run (not timed)."""

    def to_dict(self) -> dict:
        return asdict(self)


def policy_speed(policy, scenario: Scenario, steps: int, seed: int = 0, warmup: int = 5) -> PolicySpeed:
    """Time `steps` action choices (after `warmup` untimed ones) on real observations:
    the world of `Simulator(scenario, seed)` driven by the policy itself, restarted
    untimed when an episode ends."""
    rollout = Rollout(World(scenario, num_envs=1, seed=seed))
    times, rows, resets = [], [], 0
    for k in range(warmup + steps):
        turn = rollout.turn()
        resets += len(turn.restarted)
        start = time.perf_counter()
        actions = policy.act(turn.observation.rows(turn.rows))
        elapsed = time.perf_counter() - start
        if k >= warmup:
            times.append(elapsed)
            rows.append(len(turn.rows))
        rollout.step(actions)
    ms = 1e3 * np.array(times)
    rows_mean = float(np.mean(rows))
    return PolicySpeed(
        policy=policy.name,
        scenario=scenario.name,
        pursuers=scenario.pursuers,
        steps=steps,
        rows_mean=rows_mean,
        ms_per_step=float(ms.mean()),
        ms_p50=float(np.percentile(ms, 50)),
        ms_p90=float(np.percentile(ms, 90)),
        us_per_pursuer=float(1e3 * ms.mean() / rows_mean),
        resets=resets,
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

    def to_dict(self) -> dict:
        return {key: value for key, value in asdict(self).items() if key != "per_episode"}


def backend_speeds(policy, scenarios: Sequence[Scenario], episodes: int, seed: int, workers: int,
                   backends: Sequence[str] = ("local", "ray"), repeat: int = 1,
                   max_steps: int | None = None) -> list[BackendSpeed]:
    """Open each backend with `workers` workers (a Ray backend starts its own local
    instance), then evaluate `policy` on each scenario in turn (`episodes` each, episode k
    with seed + k) on one backend after the other, `repeat` rounds, so that a load that
    drifts meets them alike; each backend's best round counts. Closing is not timed."""
    with ExitStack() as stack:
        opened, start_s = {}, {}
        for name in backends:
            start = time.perf_counter()
            opened[name] = stack.enter_context(open_backend(name, workers))
            start_s[name] = time.perf_counter() - start
        best = dict.fromkeys(backends, math.inf)
        per_episode = {}
        for _ in range(repeat):
            for name in backends:
                start = time.perf_counter()
                results = [evaluate_policy(policy, scenario, episodes, seed, max_steps=max_steps, backend=opened[name])
                           for scenario in scenarios]
                best[name] = min(best[name], time.perf_counter() - start)
                per_episode[name] = tuple(m for result in results for m in result.per_episode)
    total = episodes * len(scenarios)
    return [
        BackendSpeed(backend=name, workers=workers, episodes=total, start_s=start_s[name], run_s=best[name],
                     episodes_per_s=total / best[name], per_episode=per_episode[name])
        for name in backends
    ]
