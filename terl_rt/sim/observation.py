"""Pursuer observations in the layout of the ONNX policy contract (world.md section 5).

Each observation has four token groups plus a mask, in the observer's ego frame:
ego [4], teammates [P=5, 7], evaders [E, 7], obstacles [O=5, 5], mask [1+P+E+O];
this module defines that layout (names, feature widths, slots), and the ONNX contract
(terl_rt.policy.contract) and the PettingZoo spaces (terl_rt.envs) take it from here.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from terl_rt.sim.dynamics import as_complex
from terl_rt.sim.geometry import (
    Geometry,
    SlotGroup,
    bearing,
    candidate_key,
    entity_table,
    heading,
    nearest_slots,
    per_entity,
    take,
    take_rows,
)
from terl_rt.sim.params import WorldParams
from terl_rt.sim.perception import perception_reach
from terl_rt.sim.state import WorldState

EGO_FEATURES = 4
"""ego token: [vx, vy (m/s, ego frame), d_nearest (m), pursuit_status (0/1)]."""
TEAMMATE_FEATURES = 7
"""teammate token: [px, py (m), vx, vy (m/s), d (m), bearing (rad), pursuit_status]."""
EVADER_FEATURES = 7
"""evader token: [px, py (m), vx, vy (m/s), d (m), bearing (rad), heading (rad, [0, 2pi))]."""
OBSTACLE_FEATURES = 5
"""obstacle token: [px, py (m), r (m), d (m), bearing (rad)]."""
INPUT_NAMES: tuple[str, ...] = ("ego", "teammates", "evaders", "obstacles", "mask")
"""The observation's arrays in `Observation.as_inputs()` order (the ONNX contract's inputs, in call order)."""
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
        """The ONNX contract inputs by name (INPUT_NAMES, the names of their fields here)."""
        return {name: getattr(self, name) for name in INPUT_NAMES}

    def take(self, index: np.ndarray) -> Observation:
        """The entries at `index` [K] int of the first leading axis: the environments of
        observations with leading shape [B, N] ([K, N] out), the rows of [R] ones ([K] out)."""
        return Observation(**{f.name: getattr(self, f.name)[index] for f in dataclasses.fields(self)})

    def rows(self, index: np.ndarray) -> Observation:
        """The rows at flat indices `index` [R] (b * N + n) of observations with leading
        shape [B, N]: leading shape [R]."""
        def cut(array: np.ndarray) -> np.ndarray:
            return array.reshape((-1,) + array.shape[2:])[index]

        return Observation(
            ego=cut(self.ego), teammates=cut(self.teammates), evaders=cut(self.evaders),
            obstacles=cut(self.obstacles), mask=cut(self.mask), pursuer_index=cut(self.pursuer_index),
        )


def pursuit_status(geometry: Geometry, related_distance: float) -> np.ndarray:
    """[B, N] bool: the pursuer's nearest evader is within `related_distance` m. As in the
    published simulator, the nearest of *every* evader, encircled ones included."""
    return (geometry.pursuer_evader <= related_distance).any(axis=-1)


@lru_cache(maxsize=64)
def observation_groups(num_pursuers: int, num_evaders: int, num_obstacles: int, evader_slots: int) -> tuple[SlotGroup, ...]:
    """Entity columns and slots of the teammate, evader and obstacle groups, in token order."""
    obstacles = num_pursuers + num_evaders
    return (
        SlotGroup(0, num_pursuers, TEAMMATE_SLOTS),
        SlotGroup(num_pursuers, obstacles, evader_slots),
        SlotGroup(obstacles, obstacles + num_obstacles, OBSTACLE_SLOTS),
    )


OBSTACLE_COLUMNS = [0, 1, 6, 4, 5]
"""Obstacle token columns within the shared slot features (px, py, vx, vy, d, bearing, extra)."""


def pursuer_observations(
    state: WorldState, geometry: Geometry, params: WorldParams, evader_slots: int
) -> Observation:
    """Observations of every pursuer of every environment: leading shape [B, N].

    Rows of collided pursuers are computed like the others and carry no meaning.
    Teammates are the perceived pursuers of `state.pursuer_perceived` (a pursuer that
    collided in the last step still shows, world.md section 6); encircled evaders are
    perceived by nobody. Pursuit status is `state.pursuer_pursuing`.

    The three groups share one pass: every slot (teammates, then evaders, then
    obstacles; S = 5 + E + 5) gets the same features [px, py, vx, vy, d, bearing,
    extra] in the ego frame, where extra is the teammate's pursuit status, the
    evader's heading or the obstacle's radius; each group's tokens are its columns.
    """
    num_envs, num_pursuers = state.pursuer_active.shape
    num_evaders, num_obstacles = state.evader_active.shape[1], state.obstacle_r.shape[1]
    distance = geometry.distance[:, :num_pursuers]  # [B, N, T + 1] m
    to_ego = np.exp(-1j * state.pursuer_theta)  # [B, N]: rotation by -theta
    pursuer_vel = as_complex(state.pursuer_vel)
    status = state.pursuer_pursuing.astype(np.float64)

    # ego: own velocity in own frame, nearest obstacle distance (capped at R), status.
    ego_vel = pursuer_vel * to_ego
    ego = np.empty((num_envs, num_pursuers, EGO_FEATURES), np.float32)
    ego[..., 0] = ego_vel.real
    ego[..., 1] = ego_vel.imag
    ego[..., 2] = params.perception_radius
    if num_obstacles:
        np.minimum(ego[..., 2], geometry.pursuer_obstacle.min(axis=-1), out=ego[..., 2], casting="unsafe")
    ego[..., 3] = status

    # Candidates: perceived active teammates other than oneself, active evaders at
    # any distance, perceived obstacles.
    limit = per_entity(
        np.where(state.pursuer_perceived, perception_reach(params.robot_radius, params), -1.0),
        np.where(state.evader_active, np.inf, -1.0),
        perception_reach(state.obstacle_r, params),
        blank=-1.0,
    )
    key = candidate_key(distance, 0, limit)
    columns = nearest_slots(key, observation_groups(num_pursuers, num_evaders, num_obstacles, evader_slots))
    dist = take_rows(key, columns)  # [B, N, S] m, inf in empty slots
    absent = dist == np.inf

    # Each slot's entity: position, velocity and extra feature.
    slot = take(
        entity_table(geometry, (pursuer_vel, as_complex(state.evader_vel), 0.0), (status, 0.0, state.obstacle_r)),
        columns,
    )  # [B, N, S, 3]
    rotation = to_ego[:, :, None]
    pos = (slot[..., 0] - geometry.pursuer_z[:, :, None]) * rotation
    vel = slot[..., 1] * rotation

    tokens = np.empty(columns.shape + (TEAMMATE_FEATURES,), np.float32)  # [B, N, S, 7]
    tokens[..., 0] = pos.real
    tokens[..., 1] = pos.imag
    tokens[..., 2] = vel.real
    tokens[..., 3] = vel.imag
    tokens[..., 4] = dist
    tokens[..., 5] = bearing(pos)
    tokens[..., 6] = slot[..., 2].real
    evader_part = slice(TEAMMATE_SLOTS, TEAMMATE_SLOTS + evader_slots)
    tokens[:, :, evader_part, 6] = heading(vel[:, :, evader_part])
    tokens[absent] = 0.0  # empty slots are all zeros

    mask = np.empty((num_envs, num_pursuers, 1 + columns.shape[-1]), bool)
    mask[..., 0] = True
    np.logical_not(absent, out=mask[..., 1:])
    return Observation(
        ego=ego,
        teammates=tokens[:, :, :TEAMMATE_SLOTS].copy(),
        evaders=tokens[:, :, evader_part].copy(),
        obstacles=tokens[:, :, evader_part.stop :][..., OBSTACLE_COLUMNS],
        mask=mask,
        pursuer_index=np.repeat(np.arange(num_pursuers)[None], num_envs, axis=0),
    )
