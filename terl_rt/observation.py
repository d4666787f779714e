"""Pursuer observations in the layout of the ONNX policy contract (world.md section 5).

Each observation has four token groups plus a mask, in the observer's ego frame:
ego [4], teammates [P=5, 7], evaders [E, 7], obstacles [O=5, 5], mask [1+P+E+O].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terl_rt.dynamics import as_complex
from terl_rt.geometry import Geometry, bearing, gather, heading, nearest_slots, not_self
from terl_rt.params import WorldParams
from terl_rt.state import WorldState

EGO_FEATURES = 4
"""ego token: [vx, vy (m/s, ego frame), d_nearest (m), pursuit_status (0/1)]."""
TEAMMATE_FEATURES = 7
"""teammate token: [px, py (m), vx, vy (m/s), d (m), bearing (rad), pursuit_status]."""
EVADER_FEATURES = 7
"""evader token: [px, py (m), vx, vy (m/s), d (m), bearing (rad), heading (rad, [0, 2pi))]."""
OBSTACLE_FEATURES = 5
"""obstacle token: [px, py (m), r (m), d (m), bearing (rad)]."""
TEAMMATE_SLOTS = 5
"""P: teammate slots, nearest perceived active pursuers first."""
OBSTACLE_SLOTS = 5
"""O: obstacle slots, nearest perceived obstacles first."""
ENTITY_TYPES = {"ego": 0, "teammate": 1, "evader": 2, "obstacle": 3}
"""Entity type ids, in mask order."""


@dataclass(frozen=True)
class Observation:
    """Pursuer observations, float32, with any leading shape `...` (rows of pursuers).

    `Simulator` returns one row per active pursuer (`...` = [n]); the batched world
    returns every pursuer of every environment (`...` = [B, N]).
    """

    ego: np.ndarray
    """[..., 4] float32."""
    teammates: np.ndarray
    """[..., P, 7] float32, P = 5."""
    evaders: np.ndarray
    """[..., E, 7] float32, E the scenario's evader slots."""
    obstacles: np.ndarray
    """[..., O, 5] float32, O = 5."""
    mask: np.ndarray
    """[..., 1 + P + E + O] bool: ego (always true), teammates, evaders, obstacles."""
    pursuer_index: np.ndarray
    """[...] int64: the pursuer each row belongs to."""

    def as_inputs(self) -> dict[str, np.ndarray]:
        """The ONNX contract inputs, by name: ego, teammates, evaders, obstacles, mask."""
        return {
            "ego": self.ego,
            "teammates": self.teammates,
            "evaders": self.evaders,
            "obstacles": self.obstacles,
            "mask": self.mask,
        }


def pursuit_status(
    geometry: Geometry, evader_active: np.ndarray, related_distance: float
) -> np.ndarray:
    """[B, N] float64: 1.0 where a pursuer's nearest active evader is within
    `related_distance` m, else 0.0 (evader_active [B, M] bool)."""
    near = (geometry.pursuer_evader <= related_distance) & evader_active[:, None, :]
    return near.any(axis=-1).astype(np.float64)


def _tokens(columns: list[np.ndarray], present: np.ndarray) -> np.ndarray:
    """Stack feature columns [B, X, k] into float32 tokens [B, X, k, F], zero where absent."""
    return (np.stack(columns, axis=-1) * present[..., None]).astype(np.float32)


def pursuer_observations(
    state: WorldState, geometry: Geometry, params: WorldParams, evader_slots: int
) -> Observation:
    """Observations of every pursuer of every environment: leading shape [B, N].

    Rows of collided pursuers are computed like the others and carry no meaning.
    Collided pursuers and encircled evaders are perceived by nobody.
    """
    num_envs, num_pursuers = state.pursuer_active.shape
    own_z = geometry.pursuer_z[..., None]  # [B, N, 1] complex m
    to_ego = np.exp(-1j * state.pursuer_theta)[..., None]  # [B, N, 1]: rotation by -theta
    pursuer_vel, evader_vel = as_complex(state.pursuer_vel), as_complex(state.evader_vel)
    status = pursuit_status(geometry, state.evader_active, params.related_distance)

    # ego: own velocity in own frame, nearest obstacle distance (capped at R), status.
    ego_vel = pursuer_vel * to_ego[..., 0]
    d_nearest = np.full((num_envs, num_pursuers), params.perception_radius)
    if geometry.pursuer_obstacle.shape[-1]:
        d_nearest = np.minimum(d_nearest, geometry.pursuer_obstacle.min(axis=-1))
    ego = np.stack([ego_vel.real, ego_vel.imag, d_nearest, status], axis=-1).astype(np.float32)

    # teammates: nearest perceived active pursuers other than oneself.
    perceived = (
        (geometry.pursuer_pursuer <= params.perception_radius + params.robot_radius)
        & state.pursuer_active[:, None, :]
        & not_self(num_pursuers)
    )
    idx, present_t, dist = nearest_slots(geometry.pursuer_pursuer, perceived, TEAMMATE_SLOTS)
    pos = (gather(geometry.pursuer_z, idx) - own_z) * to_ego
    vel = gather(pursuer_vel, idx) * to_ego
    teammates = _tokens(
        [pos.real, pos.imag, vel.real, vel.imag, dist, bearing(pos), gather(status, idx)], present_t
    )

    # evaders: nearest active evaders at any distance.
    idx, present_e, dist = nearest_slots(geometry.pursuer_evader, state.evader_active[:, None, :], evader_slots)
    pos = (gather(geometry.evader_z, idx) - own_z) * to_ego
    vel = gather(evader_vel, idx) * to_ego
    evaders = _tokens([pos.real, pos.imag, vel.real, vel.imag, dist, bearing(pos), heading(vel)], present_e)

    # obstacles: nearest perceived obstacles.
    reach = params.perception_radius + state.obstacle_r[:, None, :]
    idx, present_o, dist = nearest_slots(geometry.pursuer_obstacle, geometry.pursuer_obstacle <= reach, OBSTACLE_SLOTS)
    pos = (gather(geometry.obstacle_z, idx) - own_z) * to_ego
    obstacles = _tokens([pos.real, pos.imag, gather(state.obstacle_r, idx), dist, bearing(pos)], present_o)

    mask = np.concatenate(
        [np.ones((num_envs, num_pursuers, 1), bool), present_t, present_e, present_o],
        axis=-1,
    )
    return Observation(
        ego=ego,
        teammates=teammates,
        evaders=evaders,
        obstacles=obstacles,
        mask=mask,
        pursuer_index=np.zeros((num_envs, 1), np.int64) + np.arange(num_pursuers),
    )
