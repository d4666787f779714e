"""The encirclement test (world.md section 7)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terl_rt.sim.dynamics import TWO_PI
from terl_rt.sim.geometry import Geometry, heading
from terl_rt.sim.params import WorldParams
from terl_rt.sim.perception import perceived_pursuers
from terl_rt.sim.state import WorldState


@dataclass(frozen=True)
class Encirclement:
    """Outcome of one step's encirclement test."""

    evader_captured: np.ndarray
    """[B, M] bool: evaders encircled this step."""
    pursuer_target: np.ndarray
    """[B, N] int64: the evader each pursuer encircled this step, -1 for none."""
    ring_size: np.ndarray
    """[B, N] int64: n_k, pursuers in that pursuer's ring (itself included), 0 for none."""
    gap_std: np.ndarray
    """[B, N] float64 rad: standard deviation of the ring's bearing gaps, 0 for none."""


def ring_gaps(bearings: np.ndarray, member: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cyclic gaps between sorted bearings of ring members.

    bearings [C, N] rad in [0, 2pi); member [C, N] bool, at least 1 member a row.
    Returns (max gap [C], min gap [C], std of gaps [C], count [C]) in rad.
    """
    count = member.sum(-1)
    ordered = np.sort(np.where(member, bearings, 2 * TWO_PI), axis=-1)  # non-members last
    gaps = np.diff(ordered, axis=-1)  # [C, N-1]; only the first count-1 are real
    real = np.arange(gaps.shape[-1]) < (count - 1)[:, None]
    rows = np.arange(len(count))
    wrap = ordered[:, 0] + TWO_PI - ordered[rows, count - 1]
    gaps = np.concatenate([np.where(real, gaps, np.nan), wrap[:, None]], -1)
    return np.nanmax(gaps, -1), np.nanmin(gaps, -1), np.nanstd(gaps, -1), count


def remember_perceived(state: WorldState, geometry: Geometry, params: WorldParams, present: np.ndarray) -> None:
    """Record in state.pursuer_last_seen whom each present pursuer ([B, N] bool) perceives
    now; a pursuer's row stays as it was from the step it collided on."""
    seen = perceived_pursuers(geometry, present, params)
    state.pursuer_last_seen = np.where(present[:, :, None], seen, state.pursuer_last_seen)


def encircle(state: WorldState, geometry: Geometry, params: WorldParams, present: np.ndarray) -> Encirclement:
    """The encirclement test of every pursuer p against every active evader j.

    present [B, N] bool: the pursuers that count in this step, those active at its
    start (a pursuer that collides in this step still counts; world.md section 6).
    state.pursuer_last_seen [B, N, N] holds whom each pursuer perceived in its last
    step, this one for present pursuers; a pursuer that collided earlier tests from
    where it stopped with those teammates (world.md section 7), never as a helper.

    1. |p - j| <= d_encircle; 2. at least 2 present pursuers that p perceived are
    strictly within d_encircle of j; 3. the bearings around j of those and p leave
    cyclic gaps with max <= psi and max <= kappa * min. A pursuer makes at most one
    capture a step (the first evader in index order that passes); every evader
    chosen by some pursuer is encircled.
    """
    p = params
    num_envs, num_pursuers = state.pursuer_active.shape
    num_evaders = state.evader_active.shape[1]
    close = (geometry.pursuer_evader <= p.d_encircle) & state.evader_active[:, None, :]  # [B, N, M]
    strictly_close = (geometry.pursuer_evader < p.d_encircle) & present[:, :, None] & state.evader_active[:, None, :]
    perceives = state.pursuer_last_seen & present[:, None, :]  # [B, N, N]
    helpers = np.matmul(perceives.astype(np.float64), strictly_close.astype(np.float64))  # [B, N, M]
    env, pursuer, evader = np.nonzero(close & (helpers >= 2))

    target = np.full((num_envs, num_pursuers), -1, np.int64)
    ring_size = np.zeros((num_envs, num_pursuers), np.int64)
    gap_std = np.zeros((num_envs, num_pursuers))
    captured = np.zeros((num_envs, num_evaders), bool)
    if len(env) == 0:
        return Encirclement(captured, target, ring_size, gap_std)

    # One row per candidate (b, p, j): the ring is p plus the perceived helpers.
    member = perceives[env, pursuer] & strictly_close[env, :, evader]  # [C, N]
    member[np.arange(len(env)), pursuer] = True
    offset = geometry.pursuer_z[env] - geometry.evader_z[env, evader][:, None]  # [C, N] complex
    bearings = heading(offset)
    max_gap, min_gap, std, count = ring_gaps(bearings, member)
    passed = (max_gap <= p.max_gap) & (max_gap <= p.gap_ratio * min_gap)

    # Candidates come in (b, p, j) lexicographic order: the first passing j of each
    # pursuer is its capture.
    env, pursuer, evader = env[passed], pursuer[passed], evader[passed]
    std, count = std[passed], count[passed]
    first = np.ones(len(env), bool)
    first[1:] = (env[1:] != env[:-1]) | (pursuer[1:] != pursuer[:-1])
    env, pursuer, evader = env[first], pursuer[first], evader[first]
    target[env, pursuer] = evader
    ring_size[env, pursuer] = count[first]
    gap_std[env, pursuer] = std[first]
    captured[env, evader] = True
    return Encirclement(captured, target, ring_size, gap_std)
