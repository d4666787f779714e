"""Scripted evaders (world.md section 8): the paper's artificial-potential-field evader.

An evader policy maps the world to one action index per evader, [B, M] int64 into
the evader action table (terl_rt.actions.EVADER_ACTIONS). Any object with the
`EvaderPolicy.act` signature can be passed to the simulator.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from terl_rt.actions import EVADER_YAW_RATES
from terl_rt.dynamics import TWO_PI, as_complex
from terl_rt.geometry import Geometry, gather, nearest_slots, not_self
from terl_rt.params import WorldParams
from terl_rt.state import WorldState

APF_SLOTS = 5
"""nearest obstacles, pursuers and other evaders an evader takes into account."""


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

    k_rep (1/d - 1/d0) / d^n where d < d0, else 0. A clearance of exactly 0 is
    nudged to 1e-9 m to keep the published formula finite.
    """
    d = distance - radius - p.apf_body_radius
    d = np.where(d == 0.0, 1e-9, d)
    magnitude = np.where(d < p.apf_d0, p.apf_k_rep * (1.0 / d - 1.0 / p.apf_d0) / d**p.apf_n, 0.0)
    return magnitude, d


def _repulsion(state: WorldState, geometry: Geometry, p: WorldParams) -> np.ndarray:
    """Obstacle and robot forces on each evader from its 5 nearest perceived obstacles,
    pursuers and other evaders: [B, M] complex, world frame (the sums are frame-free)."""
    num_evaders = state.evader_active.shape[1]
    own_z = geometry.evader_z[..., None]
    own_vel = as_complex(state.evader_vel)[..., None]
    force = np.zeros(state.evader_active.shape, np.complex128)

    # Obstacles: along -p/|p|.
    dist = geometry.evader_obstacle
    if dist.shape[-1]:
        idx, present, d_centre = nearest_slots(dist, dist <= p.perception_radius + state.obstacle_r[:, None, :], APF_SLOTS)
        unit = (gather(geometry.obstacle_z, idx) - own_z) / np.where(present, d_centre, 1.0)
        magnitude, _ = _push(d_centre, gather(state.obstacle_r, idx), p)
        force -= (np.where(present, magnitude, 0.0) * unit).sum(-1)

    # Robots: pursuers and other evaders, only when closing in (v_ao >= 0).
    reach = p.perception_radius + p.robot_radius
    pursuer_dist = np.swapaxes(geometry.pursuer_evader, 1, 2)  # [B, M, N]
    idx_p, present_p, dist_p = nearest_slots(pursuer_dist, (pursuer_dist <= reach) & state.pursuer_active[:, None, :], APF_SLOTS)
    others = (geometry.evader_evader <= reach) & state.evader_active[:, None, :] & not_self(num_evaders)
    idx_e, present_e, dist_e = nearest_slots(geometry.evader_evader, others, APF_SLOTS)
    rel = np.concatenate([gather(geometry.pursuer_z, idx_p), gather(geometry.evader_z, idx_e)], -1) - own_z
    vel = np.concatenate([gather(as_complex(state.pursuer_vel), idx_p), gather(as_complex(state.evader_vel), idx_e)], -1)
    present = np.concatenate([present_p, present_e], -1)
    d_centre = np.concatenate([dist_p, dist_e], -1)
    unit = rel / np.where(present, d_centre, 1.0)
    v_ao = ((own_vel - vel) * unit.conj()).real
    magnitude, d = _push(d_centre, p.apf_body_radius, p)
    velocity_push = np.where((d < p.apf_d0) & (v_ao > 0), -p.apf_k_v * v_ao * (1.0 / d - 1.0 / p.apf_d0) / d, 0.0)
    along_unit = np.where(present & (v_ao >= 0), velocity_push - magnitude, 0.0)
    return force + (along_unit * unit).sum(-1)


def _boundary_force(xy: np.ndarray, p: WorldParams, arena: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World-frame wall repulsion [B, M] complex, near-wall [B, M] and outside [B, M] flags.

    Per wall at distance b (x, W - x, y, H - y): if b < d0, k (1/|b| - 1/d0) / |b|^1.5
    inward, k = k_rep * k_out outside (b < 0) else k_rep; scaled by
    k_boundary * sqrt(W * H) / 100.
    """
    width, height = arena
    walls = np.stack([xy[..., 0], width - xy[..., 0], xy[..., 1], height - xy[..., 1]], -1)  # [B, M, 4]
    inward = np.array([1.0, -1.0, 1.0, -1.0])
    b = np.maximum(np.abs(walls), 1e-9)
    gain = np.where(walls < 0, p.apf_k_rep * p.apf_k_out, p.apf_k_rep)
    push = np.where(walls < p.apf_d0, gain * (1.0 / b - 1.0 / p.apf_d0) / b**1.5, 0.0) * inward
    scale = p.apf_k_boundary * np.sqrt(width * height) / 100.0
    force = (push[..., 0] + push[..., 1] + 1j * (push[..., 2] + push[..., 3])) * scale
    outside = (walls < 0).any(-1)
    near_wall = (walls < p.apf_d0 / 2).any(-1)
    return force, near_wall, outside
