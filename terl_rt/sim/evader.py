"""Scripted evaders (world.md section 8): the paper's artificial-potential-field evader.

An evader policy maps the world to one action index per evader, [B, M] int64 into
the evader action table (terl_rt.sim.actions.EVADER_ACTIONS). Any object with the
`EvaderPolicy.act` signature can be passed to the simulator.
"""

from __future__ import annotations

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


def _repulsion(state: WorldState, geometry: Geometry, p: WorldParams) -> np.ndarray:
    """Obstacle and robot forces on each evader from its 5 nearest perceived obstacles,
    pursuers and other evaders: [B, M] complex, world frame (the sums are frame-free).

    Slots: APF_SLOTS obstacles, then APF_SLOTS pursuers, then APF_SLOTS evaders.
    An empty slot has an infinite distance, so its unit vector and force are 0.
    """
    num_pursuers, num_evaders = geometry.num_pursuers, geometry.num_evaders
    num_obstacles = state.obstacle_r.shape[1]
    distance = geometry.distance[:, num_pursuers:]  # [B, M, T + 1] m
    own_z = geometry.evader_z[..., None]
    own_vel = as_complex(state.evader_vel)[..., None]

    # Candidates: perceived obstacles and perceived robots other than oneself: active
    # evaders, and the pursuers of state.pursuer_perceived (those that collided in the
    # last step included, world.md section 6).
    reach = perception_reach(p.robot_radius, p)
    limit = per_entity(
        np.where(state.pursuer_perceived, reach, -1.0),
        np.where(state.evader_active, reach, -1.0),
        perception_reach(state.obstacle_r, p),
        blank=-1.0,
    )
    key = candidate_key(distance, num_pursuers, limit)
    columns = nearest_slots(key, apf_groups(num_pursuers, num_evaders, num_obstacles))
    d_centre = take_rows(key, columns)  # [B, M, 15] m, inf in empty slots

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
    return (along_unit * unit).sum(-1)


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
