"""Physical, perception, reward and evader constants of the world (world.md sections 1-10).

Every number of the spec is a default here, not a constant in code: a scenario may
override any of them (JSON field `params`). Units: metres, seconds, radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from terl_rt.sim.actions import EVADER_ACCELERATIONS, PURSUER_ACCELERATIONS


@dataclass(frozen=True)
class WorldParams:
    """The world's constants. Defaults are the paper's and its published simulator's."""

    # --- bodies and kinematics (sections 1-2)
    robot_radius: float = 0.5 * math.sqrt(2.0**2 + 1.0**2)
    """m: disc radius of pursuers and evaders (a 2.0 x 1.0 hull), for detection and collision. Valid: (0, 10]."""
    dt: float = 0.05
    """s: integration sub-step. Valid: (0, 1]."""
    substeps: int = 10
    """integration sub-steps per decision step (0.5 s). Valid: [1, 1000]."""
    pursuer_max_speed: float = 3.0
    """m/s: pursuer s_max. Valid: [1e-06, 100] (the drag max(a_set) / s_max stays finite)."""
    evader_max_speed: float = 3.5
    """m/s: evader s_max. Valid: [1e-06, 100] (the drag max(a_set) / s_max stays finite)."""

    # --- obstacles and vortices (sections 1, 3, 4)
    obstacle_radius_min: float = 1.0
    """m: obstacle radius drawn from U(min, max). Valid: (0, 100]."""
    obstacle_radius_max: float = 1.1
    """m: see obstacle_radius_min. Valid: (0, 100]."""
    vortex_core_radius: float = 0.5
    """m: Rankine core radius r0. Valid: (0, 100]."""
    vortex_edge_speed_min: float = 2.5
    """m/s: edge speed v_e ~ U(min, max); circulation Gamma = 2 pi * 0.25 * v_e. Valid: [0, 100]."""
    vortex_edge_speed_max: float = 5.0
    """m/s: see vortex_edge_speed_min. Valid: [0, 100]."""
    vortex_rel_speed_max: float = 1.0
    """m/s: v_rel_max of the same-direction core spacing rule. Valid: (0, 100]."""

    # --- reset (section 4)
    evader_spawn_margin: float = 15.0
    """m: evaders start in [margin, W - margin] x [margin, H - margin]. Valid: [0, 10000]."""
    pursuer_spawn_margin: float = 2.0
    """m: pursuers start in [margin, W - margin] x [margin, H - margin]. Valid: [0, 10000]."""
    obstacle_spawn_margin: float = 5.0
    """m: obstacle centres in [margin, W - margin] x [margin, H - margin]. Valid: [0, 10000]."""
    obstacle_clearance: float = 5.0
    """m: extra gap between an obstacle and a vortex core or another obstacle. Valid: [0, 10000]."""
    placement_tries: int = 10_000
    """candidate draws per entity before reset fails with an error naming the field. Valid: [1, 1000000]."""

    # --- perception (section 5)
    perception_radius: float = 20.0
    """m: R; an entity is perceived when the centre distance is <= R + its radius. Valid: (0, 10000]."""
    related_distance: float = 18.0
    """m: pursuit status and cooperation range. Valid: [0, 10000]."""

    # --- encirclement (section 7)
    d_encircle: float = 8.0
    """m: encirclement distance. Valid: (0, 10000]."""
    max_gap: float = math.pi
    """rad: psi, largest allowed bearing gap around the evader. Valid: (0, 2 pi]."""
    gap_ratio: float = 3.0
    """kappa: largest gap <= kappa * smallest gap. Valid: [1, 1000000]."""
    min_active_pursuers: int = 3
    """the episode ends when fewer pursuers than this remain active. Valid: [1, 1000]."""

    # --- reward (section 9)
    reward_time: float = -1.0
    """per step. Valid: [-1e6, 1e6]."""
    reward_collision: float = -80.0
    """in the step a pursuer collides. Valid: [-1e6, 1e6]."""
    reward_emergency: float = -5.0
    """when a teammate, evader or perceived obstacle is closer than d_safe. Valid: [-1e6, 1e6]."""
    d_safe: float = 4.0
    """m: emergency distance, 0.5 * d_encircle. Valid: [0, 10000]."""
    reward_guidance: float = 5.0
    """per active evader: full within d_encircle, else decaying with distance. Valid: [-1e6, 1e6]."""
    guidance_decay: float = 0.05
    """1/m: guidance = reward_guidance * exp(-decay * (d_e - d_encircle)). Valid: [0, 100]."""
    reward_cooperation: float = 5.0
    """for 3 <= P < 5 pursuers around an evader: reward * max(0, 1 - slope * (P - 3)). Valid: [-1e6, 1e6]."""
    cooperation_slope: float = 0.3
    """see reward_cooperation. Valid: [0, 100]."""
    reward_crowding: float = -10.0
    """to each of P >= 5 pursuers around one evader. Valid: [-1e6, 1e6]."""
    reward_imbalance: float = -10.0
    """to every pursuer when one evader has P < 3 while another has P > 5. Valid: [-1e6, 1e6]."""
    reward_boundary: float = -5.0
    """while outside the arena. Valid: [-1e6, 1e6]."""
    reward_completion: float = 120.0
    """encirclement: reward * (2 pi / n_k) * exp(-std(gaps)). Valid: [-1e6, 1e6]."""

    # --- APF evader (section 8)
    apf_k_rep: float = 5000.0
    """repulsion gain. Valid: [0, 1e9]."""
    apf_k_v: float = 1.0
    """velocity repulsion gain. Valid: [0, 1e6]."""
    apf_mass: float = 500.0
    """evader mass in the acceleration projection. Valid: (0, 1e9]."""
    apf_d0: float = 15.0
    """m: influence distance. Valid: (0, 10000]."""
    apf_n: float = 2.0
    """repulsion exponent. Valid: [0, 10]."""
    apf_v_min: float = 1.0
    """m/s: below this speed the evader speeds up. Valid: [0, 100]."""
    apf_k_boundary: float = 10.0
    """boundary force scale (times sqrt(W * H) / 100). Valid: [0, 1e6]."""
    apf_k_out: float = 20.0
    """boundary gain multiplier outside the arena. Valid: [0, 1e6]."""
    apf_a_threshold: float = 0.1
    """m/s^2: |a_proj| above this makes the published evader brake. Valid: [0, 1e6]."""
    apf_body_radius: float = 0.8
    """m: radius the evader's potential field gives itself and other robots. Valid: [0, 100]."""

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


PARAM_RANGES: dict[str, tuple[float, float, bool, bool]] = {
    'robot_radius': (0, 10, True, False),
    'dt': (0, 1, True, False),
    'substeps': (1, 1000, False, False),
    'pursuer_max_speed': (1e-6, 100, False, False),
    'evader_max_speed': (1e-6, 100, False, False),
    'obstacle_radius_min': (0, 100, True, False),
    'obstacle_radius_max': (0, 100, True, False),
    'vortex_core_radius': (0, 100, True, False),
    'vortex_edge_speed_min': (0, 100, False, False),
    'vortex_edge_speed_max': (0, 100, False, False),
    'vortex_rel_speed_max': (0, 100, True, False),
    'evader_spawn_margin': (0, 10000, False, False),
    'pursuer_spawn_margin': (0, 10000, False, False),
    'obstacle_spawn_margin': (0, 10000, False, False),
    'obstacle_clearance': (0, 10000, False, False),
    'placement_tries': (1, 1000000, False, False),
    'perception_radius': (0, 10000, True, False),
    'related_distance': (0, 10000, False, False),
    'd_encircle': (0, 10000, True, False),
    'max_gap': (0, 2 * math.pi, True, False),
    'gap_ratio': (1, 1000000, False, False),
    'min_active_pursuers': (1, 1000, False, False),
    'reward_time': (-1e6, 1e6, False, False),
    'reward_collision': (-1e6, 1e6, False, False),
    'reward_emergency': (-1e6, 1e6, False, False),
    'd_safe': (0, 10000, False, False),
    'reward_guidance': (-1e6, 1e6, False, False),
    'guidance_decay': (0, 100, False, False),
    'reward_cooperation': (-1e6, 1e6, False, False),
    'cooperation_slope': (0, 100, False, False),
    'reward_crowding': (-1e6, 1e6, False, False),
    'reward_imbalance': (-1e6, 1e6, False, False),
    'reward_boundary': (-1e6, 1e6, False, False),
    'reward_completion': (-1e6, 1e6, False, False),
    'apf_k_rep': (0, 1e9, False, False),
    'apf_k_v': (0, 1e6, False, False),
    'apf_mass': (0, 1e9, True, False),
    'apf_d0': (0, 10000, True, False),
    'apf_n': (0, 10, False, False),
    'apf_v_min': (0, 100, False, False),
    'apf_k_boundary': (0, 1e6, False, False),
    'apf_k_out': (0, 1e6, False, False),
    'apf_a_threshold': (0, 1e6, False, False),
    'apf_body_radius': (0, 100, False, False),
}
"""name -> (low, high, low excluded, high excluded): the valid range of each constant,
checked whenever a scenario is built (`check_param`). Bounds keep a world physical and its
cost bounded; widen one here for an experiment that needs it."""


PAIRED_RANGES: tuple[tuple[str, str], ...] = (
    ("obstacle_radius_min", "obstacle_radius_max"),
    ("vortex_edge_speed_min", "vortex_edge_speed_max"),
)
"""(min, max) pairs: min <= max."""

INTEGER_PARAMS = ("substeps", "placement_tries", "min_active_pursuers")
"""The constants that take integers (the others take any number in their range)."""


def format_range(low: float, high: float, low_open: bool, high_open: bool) -> str:
    """A range as "[low, high]" with ( ) for excluded bounds."""
    show = lambda v: "2 pi" if v == 2 * math.pi else f"{v:g}"  # noqa: E731
    return f"{'(' if low_open else '['}{show(low)}, {show(high)}{')' if high_open else ']'}"


def short_repr(value: object, limit: int = 60) -> str:
    """repr(value) cut to about `limit` characters (huge values never fill an error line)."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 10**limit:
        return f"<an integer of about {int(abs(value).bit_length() * 0.30103) + 1} digits>"
    try:
        text = repr(value)
    except (ValueError, RecursionError):
        return f"<a {type(value).__name__}>"
    return text if len(text) <= limit else text[: limit - 3] + "..."


def check_param(name: str, value: object) -> str | None:
    """Why `value` is not valid for the constant `name` (None when it is): a number of the
    right kind within PARAM_RANGES[name]. Never converts huge integers to float."""
    low, high, low_open, high_open = PARAM_RANGES[name]
    span = format_range(low, high, low_open, high_open)
    is_int = name in INTEGER_PARAMS
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        return f"must be {'an integer' if is_int else 'a number'} in {span}, got {short_repr(value)}"
    if isinstance(value, (float, np.floating)) and not math.isfinite(value):
        return f"must be a finite number in {span}, got {short_repr(value)}"
    if is_int and isinstance(value, (float, np.floating)) and not float(value).is_integer():
        return f"must be an integer in {span}, got {short_repr(value)}"
    too_low = value <= low if low_open else value < low
    too_high = value >= high if high_open else value > high
    if too_low or too_high:
        return f"must lie in {span}, got {short_repr(value)}"
    return None


def check_params(params: WorldParams) -> tuple[str, str] | None:
    """(constant name, why) of the first invalid constant of `params`, else None."""
    for name in WorldParams.field_names():
        problem = check_param(name, getattr(params, name))
        if problem:
            return name, problem
    for low_name, high_name in PAIRED_RANGES:
        low, high = getattr(params, low_name), getattr(params, high_name)
        if low > high:
            return high_name, f"must be >= params.{low_name} ({low:g}), got {high:g}"
    return None
