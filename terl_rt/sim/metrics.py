"""Episode metrics (world.md section 10)."""

from __future__ import annotations

from dataclasses import asdict, dataclass

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

    def to_dict(self) -> dict:
        return asdict(self)


def episode_metrics(state: WorldState, env: int, params: WorldParams) -> EpisodeMetrics:
    """Metrics of environment `env` of a batch, from its current state."""
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
    )

