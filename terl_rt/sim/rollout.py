"""B worlds driven in a loop, their ended episodes restarted: the loop of evaluation,
benchmarks and training, written once.

Each round has two calls. `turn()` restarts the environments whose episode ended in
the last step and says which pursuers decide now (the active ones, as flat rows
b * N + n of the [B, N] observation). `step(chosen)` scatters their action indices
into the [B, N] action array (0 for the others, which the world ignores), steps the
world and keeps the metrics of every episode that ended. Between `step` and the next
`turn`, `world.state` is the state after the step, ended episodes included.

    rollout = Rollout(World(scenario, num_envs=8, seed=0))
    while ...:
        turn = rollout.turn()
        chosen = policy.act(turn.observation.rows(turn.rows))  # [R] action indices
        step = rollout.step(chosen)  # step.outcomes: environment -> EpisodeMetrics
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.observation import Observation
from terl_rt.sim.world import StepResult, World


@dataclass(frozen=True)
class Turn:
    """Who decides in this round, and from what."""

    observation: Observation
    """[B, N, ...]: every pursuer's observation (rows of collided pursuers carry no meaning)."""
    rows: np.ndarray
    """[R] int64: flat indices b * N + n of the pursuers that decide, the active ones."""
    restarted: np.ndarray
    """[K] int64: environments whose new episode starts with this turn."""


@dataclass(frozen=True)
class RolloutStep:
    """What one round's step did."""

    actions: np.ndarray
    """[B, N] int64 fed to World.step: the chosen actions at the turn's rows, 0 elsewhere."""
    observation: Observation
    """[B, N, ...] after the step, before any restart (a replay buffer's next observation)."""
    result: StepResult
    outcomes: dict[int, EpisodeMetrics]
    """environment -> metrics of its episode that ended in this step (restarted at the next turn)."""


class Rollout:
    """Drives `world` (reset here) one round at a time: `turn()`, then `step(chosen)`."""

    def __init__(self, world: World) -> None:
        self.world = world
        self._observation = world.reset()
        self._turn: Turn | None = None

    def turn(self) -> Turn:
        """Restart the episodes that ended in the last step; the observation and the rows that decide."""
        world = self.world
        restarted = np.flatnonzero(world.done)
        if restarted.size:
            self._observation = world.reset(world.done)
        self._turn = Turn(self._observation, np.flatnonzero(world.state.pursuer_active), restarted)
        return self._turn

    def step(self, chosen: np.ndarray) -> RolloutStep:
        """Step the world with `chosen` [R] int action indices, one per row of the turn."""
        turn = self._turn
        if turn is None:
            raise RuntimeError("step: call turn() first (once per step)")
        chosen = np.asarray(chosen)
        if chosen.shape != turn.rows.shape:
            raise ValueError(f"chosen: expected shape {turn.rows.shape} (one action per deciding pursuer), got {chosen.shape}")
        if chosen.size and chosen.dtype.kind not in "iu":
            raise ValueError(f"chosen: expected integer action indices, got dtype {chosen.dtype}")
        world = self.world
        actions = np.zeros(world.state.pursuer_active.shape, np.int64)
        actions.reshape(-1)[turn.rows] = chosen
        self._observation, result = world.step(actions)
        self._turn = None
        outcomes = {int(env): world.metrics(env) for env in np.flatnonzero(world.done)}
        return RolloutStep(actions, self._observation, result, outcomes)
