"""One episode of a policy: `Simulator(scenario, seed)` driven by its greedy actions.

Each step the policy sees every active pursuer's observation in one call;
`terl_rt.sim.rollout.Rollout` scatters its greedy actions to the [N] action vector
(collided pursuers get 0, which the simulator ignores). `episode_steps` yields the
episode's steps as it takes them (what a Ray task streams back), `run_episode` hands them
to a callback (what a process or the evaluating process itself does).
"""

from __future__ import annotations

from collections.abc import Callable, Generator

import numpy as np

from terl_rt.logs.format import StepRecord
from terl_rt.policy.onnx_policy import ContractError, OnnxPolicy
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.rollout import Rollout
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.simulator import StepInfo
from terl_rt.sim.state import snapshot
from terl_rt.sim.world import World


class PolicyOutputError(ContractError):
    """A policy returned a non-finite q-value or target weight during a run (a user error:
    the policy file is at fault, not the runtime)."""


def check_finite_output(policy: OnnxPolicy, q_values: np.ndarray, target_weights: np.ndarray | None,
                        step: int, seed: int) -> None:
    """Raise PolicyOutputError naming the policy, the step and the seed when an output is NaN or Inf."""
    for name, values in (("q_values", q_values), ("target_weights", target_weights)):
        if values is None or np.isfinite(values).all():
            continue
        row = int(np.argwhere(~np.isfinite(values))[0][0])
        bad = values.reshape(len(values), -1)[row]
        bad = bad[~np.isfinite(bad)][0]
        raise PolicyOutputError(
            f"policy {policy.name} ({policy.path}) output a non-finite {name} ({bad}) at step {step} "
            f"of the episode with seed {seed} (decision row {row}); the run is stopped"
        )


def episode_steps(
    policy: OnnxPolicy, scenario: Scenario, seed: int, record: bool = True,
) -> Generator[StepRecord, None, EpisodeMetrics]:
    """Run one episode of `Simulator(scenario, seed)` (its world: environment 0 of
    `World(scenario, 1, seed)`) with the policy's greedy actions.

    Yields a StepRecord for the state after reset (step 0) and after each step when
    `record`, nothing otherwise; returns the episode's metrics (`yield from` gives them).
    """
    world = World(scenario, num_envs=1, seed=seed)
    rollout = Rollout(world)
    if record:
        yield StepRecord(step=0, state=snapshot(world.state, 0))
    while True:
        turn = rollout.turn()
        output = policy.evaluate(turn.observation.rows(turn.rows))
        check_finite_output(policy, output.q_values, output.target_weights, int(world.state.steps[0]) + 1, seed)
        step = rollout.step(output.actions)
        if record:
            yield StepRecord(
                step=int(world.state.steps[0]), state=snapshot(world.state, 0), pursuer_actions=step.actions[0],
                decided=turn.rows, target_weights=output.target_weights, info=StepInfo.of(step.result),
            )
        if step.outcomes:
            return step.outcomes[0]


def run_episode(
    policy: OnnxPolicy,
    scenario: Scenario,
    seed: int,
    on_step: Callable[[StepRecord], None] | None = None,
) -> EpisodeMetrics:
    """`episode_steps` with every StepRecord handed to `on_step` (step 0 after reset, then
    each step) as it is taken; returns the episode's metrics."""
    steps = episode_steps(policy, scenario, seed, record=on_step is not None)
    while True:
        try:
            record = next(steps)
        except StopIteration as end:
            return end.value
        on_step(record)
