"""Pairwise geometry shared by collisions, encirclement, rewards, observations and the evader.

Computed once per step after the robots move. Points are handled as complex numbers
x + iy (a zero-copy view of [..., 2] arrays): a difference is one subtraction and a
change into a robot's frame one multiplication by exp(-i theta).
Letters: B environments, N pursuers, M evaders, O obstacles; distances in m.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from terl_rt.dynamics import as_complex
from terl_rt.state import WorldState


def pairwise_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Centre distances: complex points a [B, X], b [B, Y] (m) -> [B, X, Y] m."""
    return np.abs(a[:, :, None] - b[:, None, :])


@dataclass(frozen=True)
class Geometry:
    """Positions as complex numbers and the centre distances between every pair (m)."""

    pursuer_z: np.ndarray
    """[B, N] complex: pursuer centres x + iy."""
    evader_z: np.ndarray
    """[B, M] complex."""
    obstacle_z: np.ndarray
    """[B, O] complex."""
    pursuer_pursuer: np.ndarray
    """[B, N, N]."""
    pursuer_evader: np.ndarray
    """[B, N, M]."""
    pursuer_obstacle: np.ndarray
    """[B, N, O]."""
    evader_evader: np.ndarray
    """[B, M, M]."""
    evader_obstacle: np.ndarray
    """[B, M, O]."""

    @staticmethod
    def of(state: WorldState) -> Geometry:
        p, e, o = as_complex(state.pursuer_xy), as_complex(state.evader_xy), as_complex(state.obstacle_xy)
        return Geometry(
            pursuer_z=p,
            evader_z=e,
            obstacle_z=o,
            pursuer_pursuer=pairwise_distance(p, p),
            pursuer_evader=pairwise_distance(p, e),
            pursuer_obstacle=pairwise_distance(p, o),
            evader_evader=pairwise_distance(e, e),
            evader_obstacle=pairwise_distance(e, o),
        )


@lru_cache(maxsize=256)
def _grid(num_envs: int, num_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Broadcastable (env [B, 1, 1], row [1, X, 1]) indices for per-row gathers."""
    return np.arange(num_envs)[:, None, None], np.arange(num_rows)[None, :, None]


def nearest_slots(distance: np.ndarray, valid: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The k nearest valid entities of each observer, nearest first.

    distance [B, X, Y] m and valid [B, X, Y] bool -> (index [B, X, k] int64,
    present [B, X, k] bool, distance [B, X, k] m). Empty slots have index 0,
    present False and distance 0.
    """
    num_envs, num_rows, num = distance.shape
    key = np.where(valid, distance, np.inf)
    if num < k:  # empty columns to fill the slots
        key = np.concatenate([key, np.full((num_envs, num_rows, k - num), np.inf)], axis=-1)
    index = np.argsort(key, axis=-1)[..., :k]
    env, row = _grid(num_envs, num_rows)
    dist = key[env, row, index]
    present = dist < np.inf
    return np.where(present, index, 0), present, np.where(present, dist, 0.0)


@lru_cache(maxsize=64)
def not_self(num: int) -> np.ndarray:
    """[num, num] bool: True off the diagonal (an entity is not its own neighbour)."""
    return ~np.eye(num, dtype=bool)


def gather(values: np.ndarray, index: np.ndarray) -> np.ndarray:
    """Per-environment gather: values [B, Y, ...], index [B, X, k] -> [B, X, k, ...].

    With no entities (Y = 0) every slot is empty and gets zeros.
    """
    if values.shape[1] == 0:
        return np.zeros(index.shape + values.shape[2:], values.dtype)
    env, _ = _grid(values.shape[0], 1)
    return values[env, index]


def bearing(local: np.ndarray) -> np.ndarray:
    """Angle of ego-frame points (complex [...]) in (-pi, pi] rad -> [...]."""
    angle = np.arctan2(local.imag, local.real)
    return np.where(angle == -np.pi, np.pi, angle)


def heading(vec: np.ndarray) -> np.ndarray:
    """Direction of vectors (complex [...]) in [0, 2pi) rad -> [...]."""
    angle = np.mod(np.arctan2(vec.imag, vec.real), 2 * np.pi)
    return np.where(angle >= 2 * np.pi, 0.0, angle)  # mod of a tiny negative angle rounds to 2pi
