"""Scripted evaders (world.md section 8) and their registry: the paper's artificial-potential-field
evader and the others a scenario can name (docs/simulator.md, "Evaders").

An evader policy maps the world to one action index per evader, [B, M] int64 into
the evader action table (terl_rt.sim.actions.EVADER_ACTIONS). Any object with the
`EvaderPolicy.act` signature can be passed to the simulator; `EVADERS` names the ones a
scenario's `evader` field, the command line, the logs and training choose from.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import Protocol

import numpy as np

from terl_rt.sim.actions import EVADER_YAW_RATES
from terl_rt.sim.dynamics import TWO_PI, as_complex
from terl_rt.sim.geometry import Geometry, SlotGroup, candidate_key, entity_table, nearest_slots, per_entity, take, take_rows
from terl_rt.sim.params import WorldParams
from terl_rt.sim.perception import perception_reach
from terl_rt.sim.state import WorldState

APF_SLOTS = 5
"""nearest obstacles, pursuers and other evaders an evader takes into account."""
ROBOT_SLOTS = np.arange(3 * APF_SLOTS) >= APF_SLOTS
"""[15] bool: the APF slots that hold robots (pursuers, evaders) rather than obstacles."""
PURSUER_SLOTS = slice(APF_SLOTS, 2 * APF_SLOTS)
"""the APF slots that hold pursuers."""
BRAKE_STRAIGHT = 2
"""evader action (a = -0.4 m/s^2, w = 0): index 0 * 5 + 2."""
GAP_PULL = 50.0
"""N, in the APF's force units (world.md section 8): the widest gap's pull on a `WidestGapEvader`.
An obstacle's push outweighs it within a clearance of about 4.1 m (5000 (1/4.1 - 1/15) / 4.1^2
= 52), a wall's within about 10.5 m of a 120 m arena (12 x 5000 (1/10.5 - 1/15) / 10.5^1.5 = 48)."""
NO_BEARING = 10.0
"""rad: the bearing of an empty pursuer slot in `widest_gap_bisector`, beyond every real one
(which lie in (-pi, pi]), so that a sort puts empty slots last."""


class EvaderPolicy(Protocol):
    def act(self, state: WorldState, geometry: Geometry, params: WorldParams, arena: tuple[float, float]) -> np.ndarray:
        """Action indices [B, M] int64 (ignored for encircled evaders)."""
        ...


class ConstantEvader:
    """Every evader takes the same action every step (a test and baseline evader)."""

    def __init__(self, action: int) -> None:
        self.action = int(action)

    def act(self, state, geometry, params, arena) -> np.ndarray:
        return np.full(state.evader_active.shape, self.action, np.int64)


class PublishedAPFEvader:
    """The APF evader of the paper's results, with the published code's quirks:

    - the world-frame boundary force is added to the ego-frame forces as they are;
    - any projected acceleration above the threshold makes it brake (index 0, -0.4);
    - outside the arena it brakes when the force points along its velocity.
    """

    def act(self, state: WorldState, geometry: Geometry, params: WorldParams, arena: tuple[float, float]) -> np.ndarray:
        p = params
        to_ego = np.exp(-1j * state.evader_theta)  # [B, M]: rotation by -theta
        v_own = as_complex(state.evader_vel) * to_ego  # ego-frame velocity, complex m/s
        boundary, near_wall, outside = _boundary_force(state.evader_xy, p, arena)
        # The published mix of frames: ego-frame repulsion plus world-frame boundary force.
        total = _repulsion(state, geometry, p) * to_ego + boundary

        speed = np.abs(v_own)
        moving = speed > 1e-3
        v_angle = np.where(moving, np.angle(v_own), 0.0)
        delta = np.mod(np.angle(total) - v_angle + np.pi, TWO_PI) - np.pi
        gap = np.abs(EVADER_YAW_RATES - delta[..., None])  # [B, M, 5]
        gap_nonzero = np.where(EVADER_YAW_RATES != 0.0, gap, np.inf)
        yaw_index = np.where(near_wall, gap_nonzero.argmin(-1), gap.argmin(-1))

        heading_unit = np.where(moving, v_own / np.where(moving, speed, 1.0), 1.0)
        a_proj = (total / p.apf_mass * heading_unit.conj()).real  # (F/m) . unit
        inside_choice = np.where(np.abs(a_proj) > p.apf_a_threshold, 0, np.where(speed < p.apf_v_min, 2, 1))
        outside_choice = np.where((total * v_own.conj()).real > 0, 0, 2)
        accel_index = np.where(outside, outside_choice, inside_choice)
        return (accel_index * len(EVADER_YAW_RATES) + yaw_index).astype(np.int64)


class StillEvader(ConstantEvader):
    """Targets that stand still: every evader brakes and never turns (a = -0.4, w = 0).

    From its start speed (at most 3.5 m/s) it comes to rest within 9 s and then moves only
    as the currents carry it (world.md section 3); in a world without vortex cores it stays put.
    """

    def __init__(self) -> None:
        super().__init__(BRAKE_STRAIGHT)


class WidestGapEvader:
    """An evader that heads for the widest gap in the ring forming around it.

    It perceives what the APF evader perceives (world.md section 8): its 5 nearest perceived
    pursuers (centre within R + r, those that collided in the last step included) and its 5
    nearest perceived obstacles. The bearings of those pursuers split the circle around it
    into angular gaps; it steers for the bisector of the widest (`widest_gap_bisector`), a
    pull of GAP_PULL along it, plus the APF's obstacle pushes and wall force, all in the world
    frame (without the published evader's mix of frames). Seeing no pursuer it holds its heading.

    Turning: the yaw rate whose turn in one decision step (w dt substeps) comes closest to the
    angle from its heading to the total force, ties to the first in table order. Accelerating:
    seeing pursuers, +0.4 while that angle is within pi/2 (it flees at full speed), else -0.4
    (a slower turn is a tighter one); seeing none, the APF's free rule: +0.4 below v_min, else 0.
    """

    def act(self, state: WorldState, geometry: Geometry, params: WorldParams, arena: tuple[float, float]) -> np.ndarray:
        p = params
        columns, d_centre = _apf_slots(state, geometry, p)
        seen = np.isfinite(d_centre[..., PURSUER_SLOTS])  # [B, M, 5]
        offset = take(geometry.entity_z, columns[..., PURSUER_SLOTS]) - geometry.evader_z[..., None]
        sees_any = seen.any(-1)
        direction = np.where(sees_any, widest_gap_bisector(np.angle(offset), seen), state.evader_theta)  # [B, M] rad
        obstacles = _slot_forces(state, geometry, p, columns, d_centre)[..., :APF_SLOTS].sum(-1)
        total = GAP_PULL * np.exp(1j * direction) + obstacles + _boundary_force(state.evader_xy, p, arena)[0]

        delta = np.mod(np.angle(total) - state.evader_theta + np.pi, TWO_PI) - np.pi  # [B, M] rad in [-pi, pi)
        turn = EVADER_YAW_RATES * (p.dt * p.substeps)  # [5] rad turned in one decision step
        yaw_index = np.abs(turn - delta[..., None]).argmin(-1)
        slow = np.abs(as_complex(state.evader_vel)) < p.apf_v_min
        accel_index = np.where(sees_any, np.where(np.abs(delta) <= np.pi / 2, 2, 0), np.where(slow, 2, 1))
        return (accel_index * len(EVADER_YAW_RATES) + yaw_index).astype(np.int64)


def widest_gap_bisector(bearing: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """The bisector of the widest angular gap between the bearings [B, M, K] rad (world frame)
    of the `seen` [B, M, K] bool pursuers around each evader: [B, M] rad, in (-pi, 2 pi].

    Sorted, bearings b_0 <= ... <= b_{k-1} leave the gaps b_{i+1} - b_i and the one that wraps,
    b_0 + 2 pi - b_{k-1}; the bisector of gap i is b_i + gap / 2. Ties go to the gap that
    starts at the smallest bearing. One pursuer leaves one gap of 2 pi: the bisector points
    straight away from it. Rows without a seen pursuer give NO_BEARING + pi (callers mask them).
    """
    ordered = np.sort(np.where(seen, bearing, NO_BEARING), -1)  # seen bearings first, ascending
    count = seen.sum(-1, keepdims=True)  # [B, M, 1]
    index = np.arange(bearing.shape[-1])
    following = np.concatenate([ordered[..., 1:], ordered[..., :1]], -1)
    gap = np.where(index == count - 1, ordered[..., :1] + TWO_PI - ordered, following - ordered)
    gap = np.where(index < count, gap, -1.0)
    widest = gap.argmax(-1)[..., None]
    return (np.take_along_axis(ordered, widest, -1) + np.take_along_axis(gap, widest, -1) / 2)[..., 0]


def _push(distance: np.ndarray, radius: np.ndarray | float, p: WorldParams) -> tuple[np.ndarray, np.ndarray]:
    """Obstacle-style repulsion magnitude and the clearance d = |p| - r - body radius.

    k_rep (1/d - 1/d0) / d^n where d < d0, else 0 (so 0 for an infinite distance).
    A clearance of exactly 0 is nudged to 1e-9 m to keep the published formula finite.
    """
    d = distance - radius - p.apf_body_radius
    d = np.where(d == 0.0, 1e-9, d)
    magnitude = np.where(d < p.apf_d0, p.apf_k_rep * (1.0 / d - 1.0 / p.apf_d0) / d**p.apf_n, 0.0)
    return magnitude, d


@lru_cache(maxsize=64)
def apf_groups(num_pursuers: int, num_evaders: int, num_obstacles: int) -> tuple[SlotGroup, ...]:
    """Entity columns of the obstacle, pursuer and evader groups an evader takes into account."""
    obstacles = num_pursuers + num_evaders
    return (
        SlotGroup(obstacles, obstacles + num_obstacles, APF_SLOTS),
        SlotGroup(0, num_pursuers, APF_SLOTS),
        SlotGroup(num_pursuers, obstacles, APF_SLOTS),
    )


def _apf_slots(state: WorldState, geometry: Geometry, p: WorldParams) -> tuple[np.ndarray, np.ndarray]:
    """What each evader perceives: the entity columns [B, M, 15] of its APF_SLOTS nearest
    perceived obstacles, then pursuers, then other evaders, and their centre distances
    [B, M, 15] m (inf in empty slots).

    Candidates: perceived obstacles and perceived robots other than oneself: active
    evaders, and the pursuers of state.pursuer_perceived (those that collided in the
    last step included, world.md section 6).
    """
    num_pursuers, num_evaders = geometry.num_pursuers, geometry.num_evaders
    distance = geometry.distance[:, num_pursuers:]  # [B, M, T + 1] m
    reach = perception_reach(p.robot_radius, p)
    limit = per_entity(
        np.where(state.pursuer_perceived, reach, -1.0),
        np.where(state.evader_active, reach, -1.0),
        perception_reach(state.obstacle_r, p),
        blank=-1.0,
    )
    key = candidate_key(distance, num_pursuers, limit)
    columns = nearest_slots(key, apf_groups(num_pursuers, num_evaders, state.obstacle_r.shape[1]))
    return columns, take_rows(key, columns)


def _slot_forces(
    state: WorldState, geometry: Geometry, p: WorldParams, columns: np.ndarray, d_centre: np.ndarray,
) -> np.ndarray:
    """The force of each slot's entity on its evader: [B, M, 15] complex, world frame,
    from `_apf_slots`' columns and distances. An empty slot has an infinite distance,
    so its unit vector and force are 0."""
    own_z = geometry.evader_z[..., None]
    own_vel = as_complex(state.evader_vel)[..., None]

    # Each slot's entity: position, velocity and APF radius (robots: the body radius).
    slot = take(
        entity_table(
            geometry,
            (as_complex(state.pursuer_vel), own_vel[..., 0], 0.0),
            (p.apf_body_radius, p.apf_body_radius, state.obstacle_r),
        ),
        columns,
    )  # [B, M, 15, 3]

    # Obstacles push along -p/|p| by their radius; robots (radius = body radius)
    # only when closing in (v_ao >= 0), with the velocity term added.
    unit = (slot[..., 0] - own_z) / d_centre
    magnitude, d = _push(d_centre, slot[..., 2].real, p)
    v_ao = ((own_vel - slot[..., 1]) * unit.conj()).real
    velocity_push = np.where(ROBOT_SLOTS & (d < p.apf_d0) & (v_ao > 0), -p.apf_k_v * v_ao * (1.0 / d - 1.0 / p.apf_d0) / d, 0.0)
    along_unit = np.where(~ROBOT_SLOTS | (v_ao >= 0), velocity_push - magnitude, 0.0)
    return along_unit * unit


def _repulsion(state: WorldState, geometry: Geometry, p: WorldParams) -> np.ndarray:
    """Obstacle and robot forces on each evader from its 5 nearest perceived obstacles,
    pursuers and other evaders: [B, M] complex, world frame (the sums are frame-free)."""
    return _slot_forces(state, geometry, p, *_apf_slots(state, geometry, p)).sum(-1)


def _boundary_force(xy: np.ndarray, p: WorldParams, arena: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World-frame wall repulsion [B, M] complex, near-wall [B, M] and outside [B, M] flags.

    Per wall at distance b (x, y, W - x, H - y): if b < d0, k (1/|b| - 1/d0) / |b|^1.5
    inward, k = k_rep * k_out outside (b < 0) else k_rep; scaled by
    k_boundary * sqrt(W * H) / 100.
    """
    width, height = arena
    walls = np.concatenate([xy, np.array(arena) - xy], -1)  # [B, M, 4]: x, y, W - x, H - y
    b = np.maximum(np.abs(walls), 1e-9)
    gain = np.where(walls < 0, p.apf_k_rep * p.apf_k_out, p.apf_k_rep)
    push = np.where(walls < p.apf_d0, gain * (1.0 / b - 1.0 / p.apf_d0) / b**1.5, 0.0)
    scale = p.apf_k_boundary * np.sqrt(width * height) / 100.0
    force = as_complex(np.ascontiguousarray((push[..., :2] - push[..., 2:]) * scale))  # inward: +x, +y, -x, -y
    outside = (walls < 0).any(-1)
    near_wall = (walls < p.apf_d0 / 2).any(-1)
    return force, near_wall, outside


# ---------------------------------------------------------------- the registry
@dataclass(frozen=True)
class EvaderKind:
    """An evader behaviour by name: what builds it and one line on what it does."""

    name: str
    build: Callable[[], EvaderPolicy]
    """makes a fresh policy (no arguments)."""
    summary: str


DEFAULT_EVADER = "apf"
"""the evader of the paper's results and of every scenario that names none."""
EVADERS: dict[str, EvaderKind] = {}
"""Every evader a scenario can name (`Scenario.evader`), in listing order: the one registry that
scenario files, the command line, the logs and training read."""


class UnknownEvader(ValueError):
    """A name that is not in EVADERS; the message lists the known ones."""


def register_evader(name: str, build: Callable[[], EvaderPolicy], summary: str) -> EvaderKind:
    """Add an evader to EVADERS under `name` (lower case letters, digits and '-'); a name
    already there is a ValueError. A scenario that names it runs it in this process and in
    worker processes that import the module registering it."""
    if not name or not all(c.islower() or c.isdigit() or c == "-" for c in name):
        raise ValueError(f"evader name: lower case letters, digits and '-', got {name!r:.60}")
    if name in EVADERS:
        raise ValueError(f"evader {name!r}: already registered ({EVADERS[name].summary})")
    EVADERS[name] = kind = EvaderKind(name, build, summary)
    return kind


def evader_kind(name: str) -> EvaderKind:
    """The registered evader called `name`; UnknownEvader lists the known ones."""
    if not isinstance(name, str) or name not in EVADERS:
        raise UnknownEvader(f"unknown evader {name!r:.60}; the evaders are {', '.join(EVADERS)}")
    return EVADERS[name]


def build_evader(name: str) -> EvaderPolicy:
    """A fresh policy of the evader called `name` (`evader_kind`)."""
    return evader_kind(name).build()


register_evader(
    DEFAULT_EVADER, PublishedAPFEvader, "the paper's potential-field evader, published quirks included (world.md section 8)",
)
register_evader("still", StillEvader, "brakes and never turns: at rest within 9 s, then carried only by the currents")
register_evader(
    "widest-gap", WidestGapEvader,
    "heads for the bisector of the widest gap between the pursuers it perceives, around obstacles and walls",
)
