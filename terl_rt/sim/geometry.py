"""Pairwise geometry shared by collisions, encirclement, rewards, observations and the evader.

Computed once per step after the robots move: one distance matrix from every robot
to every entity. Points are handled as complex numbers x + iy (a zero-copy view of
[..., 2] arrays): a difference is one subtraction and a change into a robot's frame
one multiplication by exp(-i theta).

Entity columns, in this order: pursuers [0, N), evaders [N, N + M), obstacles
[N + M, N + M + O), then one *blank* column at T = N + M + O: a point at the origin
that is never a candidate, which empty slots point to. Robot rows are the first
N + M columns' entities: pursuers, then evaders.
Letters: B environments, N pursuers, M evaders, O obstacles; distances in m.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from terl_rt.sim.dynamics import as_complex
from terl_rt.sim.state import WorldState


@dataclass(frozen=True)
class Geometry:
    """Every entity's position as a complex number and the robot-to-entity distances (m).

    The named pairwise matrices are views of `distance`.
    """

    entity_z: np.ndarray
    """[B, T + 1] complex: pursuers, evaders, obstacles, then the blank point 0."""
    distance: np.ndarray
    """[B, N + M, T + 1]: centre distance from every robot to every entity column."""
    num_pursuers: int
    num_evaders: int

    @staticmethod
    def of(state: WorldState) -> Geometry:
        num_envs, num_pursuers = state.pursuer_active.shape
        num_evaders = state.evader_active.shape[1]
        entity_z = np.concatenate(
            [
                as_complex(state.pursuer_xy),
                as_complex(state.evader_xy),
                as_complex(state.obstacle_xy),
                np.zeros((num_envs, 1), np.complex128),
            ],
            axis=1,
        )
        robots = entity_z[:, : num_pursuers + num_evaders]
        distance = np.abs(entity_z[:, None, :] - robots[:, :, None])
        return Geometry(entity_z, distance, num_pursuers, num_evaders)

    @property
    def num_entities(self) -> int:
        """T: pursuers, evaders and obstacles (the blank column is index T)."""
        return self.entity_z.shape[1] - 1

    @property
    def pursuer_z(self) -> np.ndarray:
        """[B, N] complex: pursuer centres x + iy."""
        return self.entity_z[:, : self.num_pursuers]

    @property
    def evader_z(self) -> np.ndarray:
        """[B, M] complex."""
        return self.entity_z[:, self.num_pursuers : self.num_pursuers + self.num_evaders]

    @property
    def obstacle_z(self) -> np.ndarray:
        """[B, O] complex."""
        return self.entity_z[:, self.num_pursuers + self.num_evaders : -1]

    @property
    def pursuer_pursuer(self) -> np.ndarray:
        """[B, N, N]."""
        return self.distance[:, : self.num_pursuers, : self.num_pursuers]

    @property
    def pursuer_evader(self) -> np.ndarray:
        """[B, N, M]."""
        n = self.num_pursuers
        return self.distance[:, :n, n : n + self.num_evaders]

    @property
    def pursuer_obstacle(self) -> np.ndarray:
        """[B, N, O]."""
        n = self.num_pursuers
        return self.distance[:, :n, n + self.num_evaders : -1]

    @property
    def evader_evader(self) -> np.ndarray:
        """[B, M, M]."""
        n = self.num_pursuers
        return self.distance[:, n:, n : n + self.num_evaders]

    @property
    def evader_obstacle(self) -> np.ndarray:
        """[B, M, O]."""
        return self.distance[:, self.num_pursuers :, self.num_pursuers + self.num_evaders : -1]


@dataclass(frozen=True)
class SlotGroup:
    """`slots` slots filled with the nearest candidates among entity columns [start, stop)."""

    start: int
    stop: int
    slots: int


def nearest_slots(key: np.ndarray, groups: tuple[SlotGroup, ...]) -> np.ndarray:
    """Entity columns of each group's nearest candidates, nearest first: [B, X, S].

    key [B, X, T + 1]: distance (m) of each candidate, inf for the others; column T
    is the blank. S = the groups' slots in all, group after group. A group's slots
    beyond its candidates hold entities with key inf or the blank column T.

    One sort for all groups: columns ordered by (group, key), so that group g's
    columns, nearest first, sit at fixed positions of every row.
    """
    group_rank, positions = _slot_layout(groups, key.shape)
    order = np.lexsort((key, group_rank), axis=-1)  # [B, X, T + 1]
    return order[..., positions]


@lru_cache(maxsize=256)
def _slot_layout(groups: tuple[SlotGroup, ...], shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The sort key of `nearest_slots` that orders columns by group, and where each slot
    lies in the sorted order: (group rank [B, X, T + 1] int, positions [S] int).

    Columns outside every group come after the groups and the blank (column T) last,
    so that padding slots point to the last position, the blank.
    """
    width = shape[-1]
    rank = np.full(width, len(groups), np.int64)
    rank[width - 1] = len(groups) + 1
    positions, offset = [], 0
    for index, group in enumerate(groups):
        rank[group.start : group.stop] = index
        filled = min(group.slots, group.stop - group.start)
        positions += list(range(offset, offset + filled)) + [width - 1] * (group.slots - filled)
        offset += group.stop - group.start
    return np.broadcast_to(rank, shape), np.array(positions, np.int64)


def per_entity(pursuers: np.ndarray, evaders: np.ndarray, obstacles: np.ndarray, blank: float = 0.0) -> np.ndarray:
    """One value per entity column: [B, N], [B, M], [B, O] and the blank's value -> [B, T + 1]."""
    blanks = np.full((pursuers.shape[0], 1), blank, np.result_type(pursuers, evaders, obstacles))
    return np.concatenate([pursuers, evaders, obstacles, blanks], axis=1)


def entity_table(geometry: Geometry, *features: tuple) -> np.ndarray:
    """Each entity column's position, then its features: [B, T + 1, 1 + F] complex.

    A feature is a (pursuers, evaders, obstacles) triple of values [B, N], [B, M], [B, O]
    (or scalars); the blank column holds 0. Gathered by `take`, one table gives a slot
    all its entity's quantities at once.
    """
    n, m = geometry.num_pursuers, geometry.num_evaders
    table = np.zeros(geometry.entity_z.shape + (1 + len(features),), np.complex128)
    table[..., 0] = geometry.entity_z
    for column, (pursuers, evaders, obstacles) in enumerate(features, 1):
        table[:, :n, column] = pursuers
        table[:, n : n + m, column] = evaders
        table[:, n + m : -1, column] = obstacles
    return table


def candidate_key(distance: np.ndarray, first_row: int, limit: np.ndarray) -> np.ndarray:
    """Distances of the candidates, inf for the others: the key of `nearest_slots`.

    distance [B, X, T + 1] m from the robots of rows first_row .. first_row + X - 1;
    limit [B, T + 1] m: the largest distance at which each entity is a candidate,
    inclusive (negative: never; give the blank -1). A robot is never its own candidate.
    """
    candidate = (distance <= limit[:, None, :]) & not_self_columns(first_row, distance.shape[1], distance.shape[2])
    return np.where(candidate, distance, np.inf)


@lru_cache(maxsize=256)
def _grid(num_envs: int, num_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Broadcastable (env [B, 1, 1], row [1, X, 1]) indices for gathers."""
    return np.arange(num_envs)[:, None, None], np.arange(num_rows)[None, :, None]


def take(values: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """Per-environment gather: values [B, T + 1] by entity columns [B, X, S] -> [B, X, S]."""
    return values[_grid(values.shape[0], 1)[0], columns]


def take_rows(values: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """Per-row gather: values [B, X, T + 1] by columns [B, X, S] -> [B, X, S]."""
    env, row = _grid(*values.shape[:2])
    return values[env, row, columns]


@lru_cache(maxsize=64)
def not_self(num: int) -> np.ndarray:
    """[num, num] bool: True off the diagonal (an entity is not its own neighbour)."""
    return ~np.eye(num, dtype=bool)


@lru_cache(maxsize=64)
def not_self_columns(first_row: int, num_rows: int, width: int) -> np.ndarray:
    """[num_rows, width] bool: False where column == first_row + row (an entity is not its own neighbour)."""
    return np.arange(width)[None, :] != (first_row + np.arange(num_rows))[:, None]


def bearing(local: np.ndarray) -> np.ndarray:
    """Angle of ego-frame points (complex [...]) in (-pi, pi] rad -> [...]."""
    angle = np.arctan2(local.imag, local.real)
    return np.where(angle == -np.pi, np.pi, angle)


def heading(vec: np.ndarray) -> np.ndarray:
    """Direction of vectors (complex [...]) in [0, 2pi) rad -> [...]."""
    angle = np.mod(np.arctan2(vec.imag, vec.real), 2 * np.pi)
    return np.where(angle >= 2 * np.pi, 0.0, angle)  # mod of a tiny negative angle rounds to 2pi
