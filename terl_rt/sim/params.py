"""Physical, perception, reward and evader constants of the world (world.md sections 1-10).

Every number of the spec is a default here, not a constant in code: a scenario may
override any of them (JSON field `params`). Units: metres, seconds, radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from terl_rt.sim.actions import EVADER_ACCELERATIONS, PURSUER_ACCELERATIONS


@dataclass(frozen=True)
class WorldParams:
    """The world's constants. Defaults are the paper's and its published simulator's."""

    # --- bodies and kinematics (sections 1-2)
    robot_radius: float = 0.5 * math.sqrt(2.0**2 + 1.0**2)
    """m: disc radius of pursuers and evaders (a 2.0 x 1.0 hull), for detection and collision."""
    dt: float = 0.05
    """s: integration sub-step."""
    substeps: int = 10
    """integration sub-steps per decision step (0.5 s)."""
    pursuer_max_speed: float = 3.0
    """m/s: pursuer s_max."""
    evader_max_speed: float = 3.5
    """m/s: evader s_max."""

    # --- obstacles and vortices (sections 1, 3, 4)
    obstacle_radius_min: float = 1.0
    """m: obstacle radius drawn from U(min, max)."""
    obstacle_radius_max: float = 1.1
    """m: see obstacle_radius_min."""
    vortex_core_radius: float = 0.5
    """m: Rankine core radius r0."""
    vortex_edge_speed_min: float = 2.5
    """m/s: edge speed v_e ~ U(min, max); circulation Gamma = 2 pi * 0.25 * v_e."""
    vortex_edge_speed_max: float = 5.0
    """m/s: see vortex_edge_speed_min."""
    vortex_rel_speed_max: float = 1.0
    """m/s: v_rel_max of the same-direction core spacing rule."""

    # --- reset (section 4)
    evader_spawn_margin: float = 15.0
    """m: evaders start in [margin, W - margin] x [margin, H - margin]."""
    pursuer_spawn_margin: float = 2.0
    """m: pursuers start in [margin, W - margin] x [margin, H - margin]."""
    obstacle_spawn_margin: float = 5.0
    """m: obstacle centres in [margin, W - margin] x [margin, H - margin]."""
    obstacle_clearance: float = 5.0
    """m: extra gap between an obstacle and a vortex core or another obstacle."""
    placement_tries: int = 10_000
    """candidate draws per entity before reset fails with an error naming the field."""

    # --- perception (section 5)
    perception_radius: float = 20.0
    """m: R; an entity is perceived when the centre distance is <= R + its radius."""
    related_distance: float = 18.0
    """m: pursuit status and cooperation range."""

    # --- encirclement (section 7)
    d_encircle: float = 8.0
    """m: encirclement distance."""
    max_gap: float = math.pi
    """rad: psi, largest allowed bearing gap around the evader."""
    gap_ratio: float = 3.0
    """kappa: largest gap <= kappa * smallest gap."""
    min_active_pursuers: int = 3
    """the episode ends when fewer pursuers than this remain active."""

    # --- reward (section 9)
    reward_time: float = -1.0
    """per step."""
    reward_collision: float = -80.0
    """in the step a pursuer collides."""
    reward_emergency: float = -5.0
    """when a teammate, evader or perceived obstacle is closer than d_safe."""
    d_safe: float = 4.0
    """m: emergency distance, 0.5 * d_encircle."""
    reward_guidance: float = 5.0
    """per active evader: full within d_encircle, else decaying with distance."""
    guidance_decay: float = 0.05
    """1/m: guidance = reward_guidance * exp(-decay * (d_e - d_encircle))."""
    reward_cooperation: float = 5.0
    """for 3 <= P < 5 pursuers around an evader: reward * max(0, 1 - slope * (P - 3))."""
    cooperation_slope: float = 0.3
    """see reward_cooperation."""
    reward_crowding: float = -10.0
    """to each of P >= 5 pursuers around one evader."""
    reward_imbalance: float = -10.0
    """to every pursuer when one evader has P < 3 while another has P > 5."""
    reward_boundary: float = -5.0
    """while outside the arena."""
    reward_completion: float = 120.0
    """encirclement: reward * (2 pi / n_k) * exp(-std(gaps))."""

    # --- APF evader (section 8)
    apf_k_rep: float = 5000.0
    """repulsion gain."""
    apf_k_v: float = 1.0
    """velocity repulsion gain."""
    apf_mass: float = 500.0
    """evader mass in the acceleration projection."""
    apf_d0: float = 15.0
    """m: influence distance."""
    apf_n: float = 2.0
    """repulsion exponent."""
    apf_v_min: float = 1.0
    """m/s: below this speed the evader speeds up."""
    apf_k_boundary: float = 10.0
    """boundary force scale (times sqrt(W * H) / 100)."""
    apf_k_out: float = 20.0
    """boundary gain multiplier outside the arena."""
    apf_a_threshold: float = 0.1
    """m/s^2: |a_proj| above this makes the published evader brake."""
    apf_body_radius: float = 0.8
    """m: radius the evader's potential field gives itself and other robots."""

    @property
    def pursuer_drag(self) -> float:
        """1/s: water drag k = max(a_set) / s_max of pursuers."""
        return float(PURSUER_ACCELERATIONS.max()) / self.pursuer_max_speed

    @property
    def evader_drag(self) -> float:
        """1/s: water drag k = max(a_set) / s_max of evaders."""
        return float(EVADER_ACCELERATIONS.max()) / self.evader_max_speed

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))
