"""Episodes of a policy, batched: the episodes of a list of seeds run together in one
`World`, episode j bit for bit the one `Simulator(scenario, seed=seeds[j])` runs alone.

Each step the policy sees every deciding (active) pursuer of every running episode in one
call, and the run's acting rule (terl_rt.safety.acting: greedy, risk-aware, shielded)
turns its outputs into actions; `terl_rt.sim.rollout.Rollout` scatters them to the [B, N] action array
(collided pursuers get 0, which the world ignores), restarts each environment whose
episode ended with the next episode and drops the environments left without one.
`batch_steps` yields every episode's steps as it takes them (what a Ray task streams
back, what a process sends), `run_episode` runs one episode.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any

import dataclasses

import numpy as np

from terl_rt.logs.format import StepRecord
from terl_rt.policy.onnx_policy import ContractError, OnnxPolicy, PolicyOutput
from terl_rt.safety.acting import Acting
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.rollout import Rollout, RolloutStep, Turn
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.simulator import StepInfo
from terl_rt.sim.state import snapshot
from terl_rt.sim.world import World

BATCH_ENVS = 20
"""environments of a batch's World: the episodes that run at once (each policy call
holds their deciding pursuers; 20 large-80 episodes make 1,600 rows)."""

def check_envs(envs: int) -> int:
    """`envs`, a batch's environments, checked: a positive integer."""
    if isinstance(envs, bool) or not isinstance(envs, int) or envs < 1:
        raise ValueError(f"envs (episodes run at once) must be a positive integer, got {envs!r}")
    return envs


Message = tuple[str, int, Any]
"""("step", j, StepRecord) or ("end", j, EpisodeMetrics), j the episode's index into the seeds."""


class PolicyOutputError(ContractError):
    """A policy returned a non-finite q-value or target weight during a run (a user error:
    the policy file is at fault, not the runtime)."""


def check_finite_output(policy: OnnxPolicy, output: PolicyOutput, turn: Turn, world: World,
                        seeds: np.ndarray) -> None:
    """Raise PolicyOutputError naming the policy, the step, the episode's seed and its
    decision row when an output of the turn's rows is NaN or Inf."""
    problem = output.first_non_finite()
    if problem is None:
        return
    name, row, bad = problem
    env = int(turn.rows[row]) // world.scenario.pursuers
    first_row = int(np.searchsorted(turn.rows, env * world.scenario.pursuers))
    raise PolicyOutputError(
        f"policy {policy.name} ({policy.path}) output a non-finite {name} ({bad}) at step "
        f"{int(world.state.steps[env]) + 1} of the episode with seed {int(seeds[turn.episodes[env]])} "
        f"(decision row {row - first_row}); the run is stopped"
    )


def batch_steps(
    policy: OnnxPolicy, scenario: Scenario, seeds: Sequence[int], record: bool = True, envs: int = BATCH_ENVS,
    stop: Callable[[], bool] | None = None, acting: Acting | None = None,
) -> Iterator[Message]:
    """Run the episodes of `seeds` [K] int with the actions of `acting` (None: the policy's
    greedy ones), together in one World of min(envs, K) environments; episode j is
    `Simulator(scenario, seeds[j])`'s driven by those actions.

    Yields ("step", j, StepRecord) for episode j's state after reset (step 0) and after
    each step when `record`, then ("end", j, EpisodeMetrics); each episode's messages come
    in order, the episodes' interleaved as they run (episodes start in order). Under a
    shield the metrics count its overrides and the pursuers' decisions. `stop` is
    asked before every step: when it answers true the run ends there, its episodes unended.
    """
    seeds = np.asarray(seeds, np.int64)
    acting = acting or Acting()
    world = World(scenario, num_envs=min(envs, len(seeds)))
    rollout = Rollout(world, seeds)
    overrides, decisions = np.zeros(len(seeds), np.int64), np.zeros(len(seeds), np.int64)  # per episode
    while not rollout.finished:
        if stop is not None and stop():
            return
        turn = rollout.turn()
        if record:
            for env in np.flatnonzero(world.state.steps == 0):
                yield "step", int(turn.episodes[env]), StepRecord(step=0, state=snapshot(world.state, env))
        output = acting.act(policy, turn.observation.rows(turn.rows), scenario.params)
        check_finite_output(policy, output, turn, world, seeds)
        if output.overridden is not None:
            episode_of_row = turn.episodes[turn.rows // scenario.pursuers]
            np.add.at(overrides, episode_of_row, output.overridden)
            np.add.at(decisions, episode_of_row, 1)
        step = rollout.step(output.actions)
        if record:
            yield from _step_records(turn, step, output, world)
        for env, metrics in step.outcomes.items():
            j = int(turn.episodes[env])
            if acting.shield is not None:
                metrics = dataclasses.replace(metrics, shield_overrides=int(overrides[j]), decisions=int(decisions[j]))
            yield "end", j, metrics


def _step_records(turn: Turn, step: RolloutStep, output: PolicyOutput, world: World) -> Iterator[Message]:
    """("step", j, StepRecord) of every environment's step, its rows cut from the batch's."""
    n = world.scenario.pursuers
    bounds = np.searchsorted(turn.rows, n * np.arange(world.num_envs + 1))  # rows are ascending
    for env in range(world.num_envs):
        rows = slice(bounds[env], bounds[env + 1])
        yield "step", int(turn.episodes[env]), StepRecord(
            step=int(world.state.steps[env]), state=snapshot(world.state, env), pursuer_actions=step.actions[env],
            decided=turn.rows[rows] - n * env,
            target_weights=None if output.target_weights is None else output.target_weights[rows],
            info=StepInfo.of(step.result, env),
            overridden=None if output.overridden is None else output.overridden[rows],
        )


def run_episode(
    policy: OnnxPolicy,
    scenario: Scenario,
    seed: int,
    on_step: Callable[[StepRecord], None] | None = None,
    acting: Acting | None = None,
) -> EpisodeMetrics:
    """One episode of `Simulator(scenario, seed)` (`batch_steps` of one seed, acting by
    `acting`), every StepRecord handed to `on_step` (step 0 after reset, then each step) as
    it is taken; returns the episode's metrics."""
    for kind, _, payload in batch_steps(policy, scenario, [seed], record=on_step is not None, acting=acting):
        if kind == "end":
            return payload
        on_step(payload)
    raise AssertionError("unreachable: every episode ends")
