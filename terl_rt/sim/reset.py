"""Scenario generation (world.md section 4): rejection sampling, bounded, in spec order.

Reset is not the hot path; it loops over entities (one environment at a time) and
draws candidates in vectorised chunks: the first acceptable candidate is placed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from terl_rt.sim.scenario import Scenario, ScenarioError

_CHUNK = 64
"""candidates drawn per rejection-sampling round."""
PLACEMENT_TIME_LIMIT_S = 30.0
"""s: wall-clock time one reset may spend placing entities before it fails with a
ScenarioError (raise it here for a crowded world that needs longer)."""


@dataclass(frozen=True)
class Placement:
    """Initial entities of one environment (shapes as in InitialState)."""

    pursuers: np.ndarray
    """[N, 4]: x, y (m), heading (rad), speed (m/s)."""
    evaders: np.ndarray
    """[M, 4]."""
    obstacles: np.ndarray
    """[O, 3]: x, y, radius (m)."""
    vortices: np.ndarray
    """[V, 4]: x, y (m), Gamma (m^2/s), clockwise (1/0)."""


def _min_distance(candidates: np.ndarray, placed: np.ndarray) -> np.ndarray:
    """[K] m: distance from each candidate [K, 2] to the nearest placed point [P, 2] (inf if none)."""
    if len(placed) == 0:
        return np.full(len(candidates), np.inf)
    diff = candidates[:, None, :] - placed[None, :, :]
    return np.sqrt((diff**2).sum(-1)).min(-1)


def _place(
    rng: np.random.Generator,
    count: int,
    columns: int,
    draw: Callable[[np.random.Generator, int], np.ndarray],
    accept: Callable[[np.ndarray, np.ndarray], np.ndarray],
    tries: int,
    field: str,
    why: str,
) -> np.ndarray:
    """Place `count` entities one after another.

    draw(rng, k) -> [k, columns] candidate rows; accept(candidates, placed_rows) -> [k] bool.
    Raises ScenarioError naming `field` when an entity finds no place in `tries` draws.
    """
    placed = np.zeros((0, columns))
    deadline = time.monotonic() + PLACEMENT_TIME_LIMIT_S
    for i in range(count):
        drawn = 0
        while True:
            if time.monotonic() > deadline:
                raise ScenarioError(
                    f"{field}: placing them took longer than {PLACEMENT_TIME_LIMIT_S:g} s ({why}); the world is too "
                    "crowded (the limit is terl_rt.sim.reset.PLACEMENT_TIME_LIMIT_S)"
                )
            if drawn >= tries:
                raise ScenarioError(
                    f"{field}: could not place number {i + 1} of {count} "
                    f"in {tries} tries ({why})"
                )
            chunk = min(_CHUNK, tries - drawn)
            candidates = draw(rng, chunk)
            drawn += chunk
            ok = np.flatnonzero(accept(candidates, placed))
            if len(ok):
                placed = np.concatenate([placed, candidates[ok[:1]]])
                break
    return placed


def _uniform_in(lo: tuple[float, float], hi: tuple[float, float]) -> Callable[[np.random.Generator, int], np.ndarray]:
    return lambda rng, k: rng.uniform(lo, hi, size=(k, 2))


def place(scenario: Scenario, rng: np.random.Generator) -> Placement:
    """Draw the initial entities of one environment, in spec order:
    evaders, pursuers, vortex cores, obstacles, then every robot's heading and speed."""
    s, p = scenario, scenario.params
    width, height = s.arena
    clear = s.clear_r
    tries = p.placement_tries
    room = f"arena {width:g} x {height:g} m, clear_r {clear:g} m"

    m = p.evader_spawn_margin
    evader_xy = _place(
        rng, s.evaders, 2, _uniform_in((m, m), (width - m, height - m)),
        lambda c, placed: _min_distance(c, placed) > clear,
        tries, "evaders", room,
    )

    m = p.pursuer_spawn_margin
    init_dis = s.min_pursuer_evader_init_dis
    pursuer_xy = _place(
        rng, s.pursuers, 2, _uniform_in((m, m), (width - m, height - m)),
        lambda c, placed: (_min_distance(c, placed) > clear) & (_min_distance(c, evader_xy) > init_dis),
        tries, "pursuers", f"{room}, min_pursuer_evader_init_dis {init_dis:g} m",
    )
    robot_xy = np.concatenate([pursuer_xy, evader_xy])

    r0 = p.vortex_core_radius

    def draw_core(rng: np.random.Generator, k: int) -> np.ndarray:
        xy = rng.uniform((0.0, 0.0), (width, height), size=(k, 2))
        clockwise = rng.random(k) < 0.5
        edge_speed = rng.uniform(p.vortex_edge_speed_min, p.vortex_edge_speed_max, size=k)
        gamma = 2 * np.pi * 0.25 * edge_speed
        return np.column_stack([xy, gamma, clockwise.astype(np.float64)])

    def accept_core(c: np.ndarray, placed: np.ndarray) -> np.ndarray:
        x, y = c[:, 0], c[:, 1]
        ok = (x >= r0) & (x <= width - r0) & (y >= r0) & (y <= height - r0)
        ok &= _min_distance(c[:, :2], robot_xy) >= r0 + clear
        if len(placed):
            diff = c[:, None, :2] - placed[None, :, :2]
            dist = np.sqrt((diff**2).sum(-1))  # [K, P]
            g_c, g_p = c[:, None, 2], placed[None, :, 2]
            same = c[:, None, 3] == placed[None, :, 3]
            spaced = dist >= (g_c + g_p) / (2 * np.pi * p.vortex_rel_speed_max)
            large, small = np.maximum(g_c, g_p), np.minimum(g_c, g_p)
            free = dist - 2 * r0
            with np.errstate(divide="ignore"):
                weak = (free > 0) & (large / (2 * np.pi * np.where(free > 0, free, 1.0)) <= 0.8 * small / (2 * np.pi * r0))
            ok &= np.where(same, spaced, weak).all(-1)
        return ok

    vortices = _place(rng, s.vortices, 4, draw_core, accept_core, tries, "vortices", room)

    m = p.obstacle_spawn_margin

    def draw_obstacle(rng: np.random.Generator, k: int) -> np.ndarray:
        xy = rng.uniform((m, m), (width - m, height - m), size=(k, 2))
        radius = rng.uniform(p.obstacle_radius_min, p.obstacle_radius_max, size=k)
        return np.column_stack([xy, radius])

    def accept_obstacle(c: np.ndarray, placed: np.ndarray) -> np.ndarray:
        x, y, r = c[:, 0], c[:, 1], c[:, 2]
        ok = (x - r >= 0) & (x + r <= width) & (y - r >= 0) & (y + r <= height)
        ok &= _min_distance(c[:, :2], robot_xy) >= r + clear
        ok &= _min_distance(c[:, :2], vortices[:, :2]) > r0 + r + p.obstacle_clearance
        if len(placed):
            diff = c[:, None, :2] - placed[None, :, :2]
            dist = np.sqrt((diff**2).sum(-1))
            ok &= (dist > placed[None, :, 2] + r[:, None] + p.obstacle_clearance).all(-1)
        return ok

    obstacles = _place(rng, s.obstacles, 3, draw_obstacle, accept_obstacle, tries, "obstacles", room)

    def heading_speed(count: int, max_speed: float) -> np.ndarray:
        return np.column_stack([rng.uniform(0, 2 * np.pi, count), rng.uniform(0, max_speed, count)])

    pursuers = np.column_stack([pursuer_xy, heading_speed(s.pursuers, p.pursuer_max_speed)])
    evaders = np.column_stack([evader_xy, heading_speed(s.evaders, p.evader_max_speed)])
    return Placement(pursuers=pursuers, evaders=evaders, obstacles=obstacles, vortices=vortices)
