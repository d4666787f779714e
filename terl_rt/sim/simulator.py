"""One encirclement world with a per-pursuer API: what users and evaluation drive."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terl_rt.sim.evader import EvaderPolicy
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.observation import Observation
from terl_rt.sim.reward import REWARD_TERMS
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.state import snapshot
from terl_rt.sim.world import Seed, StepResult, World


@dataclass(frozen=True)
class StepInfo:
    """What one step did, per pursuer ([N]) and per evader ([M])."""

    reward: np.ndarray
    """[N] float64: each pursuer's reward (0 for pursuers inactive at the step start)."""
    reward_terms: dict[str, np.ndarray]
    """term name (terl_rt.sim.reward.REWARD_TERMS) -> [N] float64."""
    collided: np.ndarray
    """[N] bool: pursuers that collided in this step."""
    captured: np.ndarray
    """[M] bool: evaders encircled in this step."""
    pursuer_target: np.ndarray
    """[N] int64: evader each pursuer encircled in this step, -1 for none."""
    evader_actions: np.ndarray
    """[M] int64: the evaders' action indices."""
    terminated: bool
    """the task ended: every evader encircled, or fewer than 3 pursuers left."""
    truncated: bool
    """the step limit was reached first."""

    @staticmethod
    def of(result: StepResult, env: int = 0) -> StepInfo:
        """Environment `env`'s part of a batch's step."""
        return StepInfo(
            reward=result.reward[env],
            reward_terms={name: result.reward_terms[env, :, i] for i, name in enumerate(REWARD_TERMS)},
            collided=result.collided[env],
            captured=result.captured[env],
            pursuer_target=result.pursuer_target[env],
            evader_actions=result.evader_actions[env],
            terminated=bool(result.terminated[env]),
            truncated=bool(result.truncated[env]),
        )


class Simulator:
    """A single world: `reset()`, then `step(actions)` until `done`.

    Observations hold one row per active pursuer (`Observation.pursuer_index` says
    which); actions hold one index per pursuer, [N]. The same scenario, seed and
    actions give the same episode, bit for bit. `seed`: an int, a np.random.Generator
    (one draw gives the int) or None (fresh entropy, as NumPy's default_rng(None)).
    """

    def __init__(self, scenario: Scenario, seed: Seed = 0, evader_policy: EvaderPolicy | None = None) -> None:
        self.scenario = scenario
        self._world = World(scenario, num_envs=1, seed=seed, evader_policy=evader_policy)

    def reset(self, seed: Seed = None) -> Observation:
        """Start an episode (the next one of this seed's stream, or of `seed` when given:
        an int, or a np.random.Generator that gives one)."""
        return self._active_rows(self._world.reset(seed=seed))

    def step(self, pursuer_actions: np.ndarray) -> tuple[Observation, StepInfo]:
        """Advance one decision step (0.5 s); pursuer_actions [N] ints in [0, 9)."""
        actions = np.asarray(pursuer_actions)
        if actions.ndim != 1:
            raise ValueError(f"pursuer_actions: expected shape ({self.scenario.pursuers},), got {actions.shape}")
        observation, result = self._world.step(actions[None])
        return self._active_rows(observation), StepInfo.of(result)

    @property
    def done(self) -> bool:
        """The episode ended (or has not started)."""
        return bool(self._world.done[0])

    @property
    def success(self) -> bool:
        """Every evader is encircled."""
        return self._world.state is not None and not self._world.state.evader_active[0].any()

    def metrics(self) -> EpisodeMetrics:
        """Success, travel time, collision ratio and counts of the episode so far."""
        return self._world.metrics(0)

    def state(self) -> dict[str, np.ndarray]:
        """Copies of the world's arrays (m, rad, m/s): pursuer_xy [N, 2], pursuer_theta [N],
        pursuer_speed [N], pursuer_vel [N, 2], pursuer_active [N], pursuer_collided [N],
        evader_xy [M, 2], evader_theta [M], evader_speed [M], evader_vel [M, 2],
        evader_active [M], obstacle_xy [O, 2], obstacle_r [O], vortex_xy [V, 2],
        vortex_gamma [V], vortex_clockwise [V], step [] (sim.state.snapshot)."""
        if self._world.state is None:
            raise RuntimeError("state: call reset() first")
        return snapshot(self._world.state, 0)

    def _active_rows(self, observation: Observation) -> Observation:
        return observation.rows(np.flatnonzero(self._world.state.pursuer_active[0]))
