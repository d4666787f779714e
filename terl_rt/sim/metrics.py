"""Episode metrics (world.md section 10) and their means over episodes."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from terl_rt.sim.collisions import TOUCHED_EVADER, TOUCHED_OBSTACLE, TOUCHED_TEAMMATE
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
    collisions_teammate: int | None = None
    """collided pursuers whose disc touched a teammate in the step they collided (one that
    touched two kinds of entity counts under each); None in metrics read from logs written
    before terl-rt recorded what collisions touched."""
    collisions_evader: int | None = None
    """collided pursuers whose disc touched an evader; None as for collisions_teammate."""
    collisions_obstacle: int | None = None
    """collided pursuers whose disc touched an obstacle; None as for collisions_teammate."""

    def to_dict(self) -> dict:
        """The fields by name; the shield's two only for an episode run under it, what
        collisions touched only where it was recorded."""
        out = asdict(self)
        if self.shield_overrides is None:
            del out["shield_overrides"], out["decisions"]
        if self.collisions_teammate is None:
            del out["collisions_teammate"], out["collisions_evader"], out["collisions_obstacle"]
        return out

    @property
    def collisions_touched(self) -> dict[str, int] | None:
        """Collided pursuers by what they touched: {"teammate", "evader", "obstacle"}; None where not recorded."""
        if self.collisions_teammate is None:
            return None
        return {"teammate": self.collisions_teammate, "evader": self.collisions_evader, "obstacle": self.collisions_obstacle}


def episode_metrics(state: WorldState, env: int, params: WorldParams, team_return: float | None = None) -> EpisodeMetrics:
    """Metrics of environment `env` of a batch, from its current state and the rewards
    summed so far (`team_return`)."""
    steps = int(state.steps[env])
    collided = int((~state.pursuer_active[env]).sum())
    encircled = int((~state.evader_active[env]).sum())
    touched = state.pursuer_touched[env]
    return EpisodeMetrics(
        success=bool(not state.evader_active[env].any()),
        steps=steps,
        travel_time_s=steps * params.dt * params.substeps,
        collision_ratio=collided / state.pursuer_active.shape[1],
        evaders_encircled=encircled,
        pursuers_collided=collided,
        team_return=team_return,
        collisions_teammate=int((touched & TOUCHED_TEAMMATE > 0).sum()),
        collisions_evader=int((touched & TOUCHED_EVADER > 0).sum()),
        collisions_obstacle=int((touched & TOUCHED_OBSTACLE > 0).sum()),
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
