"""Episode metrics (world.md section 10) and their means over episodes."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from terl_rt.sim.params import WorldParams
from terl_rt.sim.state import WorldState


@dataclass(frozen=True)
class EpisodeMetrics:
    """The outcome of one episode (or of one so far)."""

    success: bool
    """every evader encircled."""
    steps: int
    """decision steps taken."""
    travel_time_s: float
    """s: steps times the decision step (0.5 s)."""
    collision_ratio: float
    """collided pursuers / pursuers."""
    evaders_encircled: int
    pursuers_collided: int
    team_return: float | None = None
    """the episode's return: the sum of every pursuer's reward over its steps (None in
    metrics read from logs written before terl-rt recorded it)."""
    shield_overrides: int | None = None
    """pursuer-steps in which the shield replaced the policy's action (terl_rt.safety.shield);
    None for an episode run without the shield."""
    decisions: int | None = None
    """pursuer-steps decided (active pursuers, summed over steps), under the shield; else None."""

    def to_dict(self) -> dict:
        """The fields by name; the shield's two only for an episode run under it."""
        out = asdict(self)
        if self.shield_overrides is None:
            del out["shield_overrides"], out["decisions"]
        return out


def episode_metrics(state: WorldState, env: int, params: WorldParams, team_return: float | None = None) -> EpisodeMetrics:
    """Metrics of environment `env` of a batch, from its current state and the rewards
    summed so far (`team_return`)."""
    steps = int(state.steps[env])
    collided = int((~state.pursuer_active[env]).sum())
    encircled = int((~state.evader_active[env]).sum())
    return EpisodeMetrics(
        success=bool(not state.evader_active[env].any()),
        steps=steps,
        travel_time_s=steps * params.dt * params.substeps,
        collision_ratio=collided / state.pursuer_active.shape[1],
        evaders_encircled=encircled,
        pursuers_collided=collided,
        team_return=team_return,
    )


@dataclass(frozen=True)
class Summary:
    """Means over the episodes of a scenario."""

    success_rate: float
    """fraction of episodes with every evader encircled."""
    travel_time_s_mean: float
    """s: mean episode duration (steps x 0.5 s)."""
    travel_time_s_std: float
    """s: population standard deviation of the duration."""
    collision_ratio_mean: float
    """mean of collided pursuers / pursuers."""
    steps_mean: float
    """mean decision steps per episode."""


def summarize(per_episode: Sequence[EpisodeMetrics]) -> Summary:
    """Means (and the travel time's spread) over episodes; NaN for no episodes."""
    if not per_episode:
        nan = float("nan")
        return Summary(nan, nan, nan, nan, nan)
    travel = np.array([m.travel_time_s for m in per_episode])
    return Summary(
        success_rate=float(np.mean([m.success for m in per_episode])),
        travel_time_s_mean=float(travel.mean()),
        travel_time_s_std=float(travel.std()),
        collision_ratio_mean=float(np.mean([m.collision_ratio for m in per_episode])),
        steps_mean=float(np.mean([m.steps for m in per_episode])),
    )
