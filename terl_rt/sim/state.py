"""The world state: a dataclass of arrays, environments first ([B, ...]).

Letters: B environments, N pursuers, M evaders, O obstacles, V vortex cores.
Units: positions in m, headings in rad in [0, 2pi), speeds in m/s.

Each field says in its metadata what one environment's array holds and whether it is
part of the world's public state: `Simulator.state()` and the /state of episode logs
carry exactly the `LOGGED_FIELDS`; the rest is bookkeeping of the rules.
"""

from __future__ import annotations

import dataclasses
from dataclasses import MISSING, dataclass, field
from typing import Any

import numpy as np


def _array(dtype: type, *, pairs: bool = False, logged: bool = True, key: str | None = None, default: Any = MISSING) -> Any:
    """A state field: `dtype` of its entries, `pairs` when one environment's array is
    rows of 2 (x, y), `logged` when Simulator.state() and logs carry it, under `key`
    (default: the field's name)."""
    return field(default=default, metadata={"dtype": dtype, "pairs": pairs, "logged": logged, "key": key})


@dataclass
class WorldState:
    """Every array of a batch of B worlds of one scenario."""

    pursuer_xy: np.ndarray = _array(np.float64, pairs=True)
    """[B, N, 2] float64, m."""
    pursuer_theta: np.ndarray = _array(np.float64)
    """[B, N] float64, rad in [0, 2pi)."""
    pursuer_speed: np.ndarray = _array(np.float64)
    """[B, N] float64, forward speed s in m/s."""
    pursuer_vel: np.ndarray = _array(np.float64, pairs=True)
    """[B, N, 2] float64, m/s: ground velocity (steer + current) of the last sub-step, world frame."""
    pursuer_active: np.ndarray = _array(np.bool_)
    """[B, N] bool: not collided."""
    evader_xy: np.ndarray = _array(np.float64, pairs=True)
    """[B, M, 2] float64, m."""
    evader_theta: np.ndarray = _array(np.float64)
    """[B, M] float64, rad in [0, 2pi)."""
    evader_speed: np.ndarray = _array(np.float64)
    """[B, M] float64, m/s."""
    evader_vel: np.ndarray = _array(np.float64, pairs=True)
    """[B, M, 2] float64, m/s, world frame."""
    evader_active: np.ndarray = _array(np.bool_)
    """[B, M] bool: not encircled yet."""
    obstacle_xy: np.ndarray = _array(np.float64, pairs=True)
    """[B, O, 2] float64, m."""
    obstacle_r: np.ndarray = _array(np.float64)
    """[B, O] float64, m."""
    vortex_xy: np.ndarray = _array(np.float64, pairs=True)
    """[B, V, 2] float64, m: core centres."""
    vortex_gamma: np.ndarray = _array(np.float64)
    """[B, V] float64, m^2/s: circulation Gamma >= 0."""
    vortex_clockwise: np.ndarray = _array(np.bool_)
    """[B, V] bool: rotation direction."""
    steps: np.ndarray = _array(np.int64, key="step")
    """[B] int64: decision steps taken in the episode."""
    pursuer_perceived: np.ndarray | None = _array(np.bool_, logged=False, default=None)
    """[B, N] bool: pursuers the others perceive and count: those active at the start of
    the last step. A pursuer that collided in step t is still perceived in everything
    step t computes after the move, and in the evaders' decision for step t + 1
    (world.md section 6). Default: a copy of pursuer_active."""
    pursuer_pursuing: np.ndarray | None = _array(np.bool_, logged=False, default=None)
    """[B, N] bool: pursuit status, some evader (encircled ones included, as in the
    published simulator) within related_distance after the last move; false after
    reset (the published pursuers start with it unset). Default: all false."""
    pursuer_last_seen: np.ndarray | None = _array(np.bool_, logged=False, default=None)
    """[B, N, N] bool: [b, i, j] when pursuer i perceived pursuer j in the last step i
    was active in (world.md section 7: a collided pursuer keeps testing encirclements
    with these teammates). Default: all false."""
    pursuer_touched: np.ndarray | None = _array(np.uint8, logged=False, default=None)
    """[B, N] uint8: for a collided pursuer, what its disc touched in the step it collided
    (terl_rt.sim.collisions.TOUCHED_TEAMMATE, _EVADER, _OBSTACLE bits); 0 for the
    others. Default: all 0."""

    def __post_init__(self) -> None:
        num_envs, num_pursuers = self.pursuer_active.shape
        if self.pursuer_perceived is None:
            self.pursuer_perceived = self.pursuer_active.copy()
        if self.pursuer_pursuing is None:
            self.pursuer_pursuing = np.zeros((num_envs, num_pursuers), bool)
        if self.pursuer_last_seen is None:
            self.pursuer_last_seen = np.zeros((num_envs, num_pursuers, num_pursuers), bool)
        if self.pursuer_touched is None:
            self.pursuer_touched = np.zeros((num_envs, num_pursuers), np.uint8)

    def copy(self) -> WorldState:
        return WorldState(**{f.name: getattr(self, f.name).copy() for f in dataclasses.fields(self)})

    def take(self, envs: np.ndarray) -> WorldState:
        """A new state of the environments `envs` [K] int, in that order (copies)."""
        return WorldState(**{f.name: getattr(self, f.name)[envs] for f in dataclasses.fields(self)})

    def assign(self, env_mask: np.ndarray, other: WorldState) -> None:
        """Overwrite the environments selected by `env_mask` [B] bool with `other`'s rows."""
        for f in dataclasses.fields(self):
            getattr(self, f.name)[env_mask] = getattr(other, f.name)[env_mask]


@dataclass(frozen=True)
class LoggedField:
    """A WorldState field of the world's public state (Simulator.state(), logged /state)."""

    name: str
    """the WorldState attribute."""
    key: str
    """its key in Simulator.state() and in a log's /state."""
    dtype: type
    """element type: np.float64, np.bool_ or np.int64."""
    pairs: bool
    """one environment's array is [K, 2] (x, y pairs), else [K] (a scalar for `step`)."""


LOGGED_FIELDS: tuple[LoggedField, ...] = tuple(
    LoggedField(f.name, f.metadata["key"] or f.name, f.metadata["dtype"], f.metadata["pairs"])
    for f in dataclasses.fields(WorldState)
    if f.metadata["logged"]
)
"""The world's public state in field order: pursuer_xy, ..., vortex_clockwise, step."""


def snapshot(state: WorldState, env: int) -> dict[str, np.ndarray]:
    """Copies of environment `env`'s arrays by LOGGED_FIELDS key (`step` a np.int64) and
    the derived pursuer_collided [N] bool (not pursuer_active): `Simulator.state()`."""
    out = {f.key: getattr(state, f.name)[env].copy() for f in LOGGED_FIELDS}
    out["pursuer_collided"] = ~out["pursuer_active"]
    return out
