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

Given `seeds`, a rollout runs exactly those episodes (what evaluation does): episode j
is the one `Simulator(scenario, seed=seeds[j])` runs, bit for bit, whatever environment
runs it and beside whatever others. The environments start episodes 0, 1, ..., each one
that ends restarts with the next episode, and once none is left the ended environments
are dropped (the world shrinks, `World.keep`) until every episode has ended (`finished`).
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
    episodes: np.ndarray | None
    """[B] int64: the episode (index into the rollout's seeds) each environment runs; None
    for a rollout without seeds."""


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
    """Drives `world` (reset here) one round at a time: `turn()`, then `step(chosen)`.

    seeds: [K] int, K >= the world's environments: the episodes to run (see the module's
    docstring); None: every environment runs its own stream of episodes without end.
    """

    def __init__(self, world: World, seeds: np.ndarray | None = None) -> None:
        self.world = world
        self._turn: Turn | None = None
        self._seeds = self._episodes = None
        self._started = self._ended = 0
        """episodes started and ended (with seeds)."""
        if seeds is not None:
            self._seeds = np.asarray(seeds)
            if self._seeds.ndim != 1 or self._seeds.dtype.kind not in "iu" or len(self._seeds) < world.num_envs:
                raise ValueError(
                    f"seeds: expected [K] int with K >= {world.num_envs} (one episode per environment at least), "
                    f"got {self._seeds.dtype} {self._seeds.shape}"
                )
            self._episodes = np.arange(world.num_envs)
            self._started = world.num_envs
            world.reseed(self._episodes, self._seeds[: world.num_envs])
        self._observation = world.reset()

    @property
    def finished(self) -> bool:
        """Every episode of the rollout's seeds has ended (never, without seeds)."""
        return self._seeds is not None and self._ended == len(self._seeds)

    def turn(self) -> Turn:
        """Restart the episodes that ended in the last step (with seeds: with the next
        episodes, dropping the environments left without one); the observation and the
        rows that decide."""
        if self.finished:
            raise RuntimeError("turn: every episode of the rollout has ended")
        world = self.world
        restarted = np.flatnonzero(world.done)
        if restarted.size and self._seeds is not None:
            restarted = self._next_episodes(restarted)
        if restarted.size:
            self._observation = world.reset(world.done)
        episodes = None if self._episodes is None else self._episodes.copy()
        self._turn = Turn(self._observation, np.flatnonzero(world.state.pursuer_active), restarted, episodes)
        return self._turn

    def _next_episodes(self, ended: np.ndarray) -> np.ndarray:
        """Give the ended environments [K] the next episodes (reseeded) and drop those left
        without one; returns the environments to restart, numbered as after the drop."""
        world = self.world
        restarted = ended[: len(self._seeds) - self._started]
        self._episodes[restarted] = self._started + np.arange(len(restarted))
        self._started += len(restarted)
        world.reseed(restarted, self._seeds[self._episodes[restarted]])
        if len(restarted) < len(ended):
            kept = np.setdiff1d(np.arange(world.num_envs), ended[len(restarted):])
            world.keep(kept)
            self._observation = self._observation.take(kept)
            self._episodes = self._episodes[kept]
            restarted = np.searchsorted(kept, restarted)
        return restarted

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
        self._ended += len(outcomes)
        return RolloutStep(actions, self._observation, result, outcomes)
