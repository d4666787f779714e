"""Builders shared by the simulator tests: tiny explicit worlds, hand-made scenarios.

Import as `from sim_helpers import ...` (tests/ is on sys.path, there is no package).
Units as in the spec: metres, seconds, radians.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from terl_rt.sim.evader import ConstantEvader
from terl_rt.sim.geometry import Geometry
from terl_rt.sim.params import WorldParams
from terl_rt.sim.scenario import InitialState, Scenario
from terl_rt.sim.state import WorldState

DEFAULT = WorldParams()
"""The spec's default constants."""
ROBOT_R = DEFAULT.robot_radius
"""m: robot disc radius, 0.5 * sqrt(5) = 1.1180."""

PURSUER_IDLE = 4
"""pursuer action (a = 0.0, w = 0): index 1 * 3 + 1."""
EVADER_IDLE = 7
"""evader action (a = 0.0, w = 0): index 1 * 5 + 2."""


def rows(values: Sequence[Sequence[float]], width: int) -> np.ndarray:
    """A [K, width] float64 array from a list of rows (K may be 0)."""
    return np.array(values, dtype=np.float64).reshape(len(values), width)


def steer_velocity(robots: np.ndarray) -> np.ndarray:
    """[K, 2] m/s: s (cos theta, sin theta) of rows [x, y, theta, speed] (no current)."""
    return np.column_stack([robots[:, 3] * np.cos(robots[:, 2]), robots[:, 3] * np.sin(robots[:, 2])])


def make_state(
    pursuers: Sequence[Sequence[float]] = (),
    evaders: Sequence[Sequence[float]] = (),
    obstacles: Sequence[Sequence[float]] = (),
    vortices: Sequence[Sequence[float]] = (),
    *,
    pursuer_vel: Sequence[Sequence[float]] | None = None,
    evader_vel: Sequence[Sequence[float]] | None = None,
    pursuer_active: Sequence[bool] | None = None,
    evader_active: Sequence[bool] | None = None,
    steps: int = 0,
) -> WorldState:
    """A WorldState of one environment (B = 1).

    pursuers, evaders: rows [x, y, theta, speed]; obstacles: rows [x, y, r];
    vortices: rows [x, y, gamma, clockwise]. Velocities default to the steer
    velocity s (cos theta, sin theta); every robot is active unless told.
    """
    p, e = rows(pursuers, 4), rows(evaders, 4)
    o, v = rows(obstacles, 3), rows(vortices, 4)
    p_vel = steer_velocity(p) if pursuer_vel is None else rows(pursuer_vel, 2)
    e_vel = steer_velocity(e) if evader_vel is None else rows(evader_vel, 2)
    p_act = np.ones(len(p), bool) if pursuer_active is None else np.array(pursuer_active, bool)
    e_act = np.ones(len(e), bool) if evader_active is None else np.array(evader_active, bool)
    return WorldState(
        pursuer_xy=np.ascontiguousarray(p[None, :, :2]),
        pursuer_theta=p[None, :, 2].copy(),
        pursuer_speed=p[None, :, 3].copy(),
        pursuer_vel=np.ascontiguousarray(p_vel[None]),
        pursuer_active=p_act[None].copy(),
        evader_xy=np.ascontiguousarray(e[None, :, :2]),
        evader_theta=e[None, :, 2].copy(),
        evader_speed=e[None, :, 3].copy(),
        evader_vel=np.ascontiguousarray(e_vel[None]),
        evader_active=e_act[None].copy(),
        obstacle_xy=np.ascontiguousarray(o[None, :, :2]),
        obstacle_r=o[None, :, 2].copy(),
        vortex_xy=np.ascontiguousarray(v[None, :, :2]),
        vortex_gamma=v[None, :, 2].copy(),
        vortex_clockwise=v[None, :, 3] > 0.5,
        steps=np.array([steps], np.int64),
    )


def stack_states(states: Sequence[WorldState]) -> WorldState:
    """One batch from single-environment states of the same counts (env axis first)."""
    return WorldState(**{
        f.name: np.ascontiguousarray(np.concatenate([getattr(s, f.name) for s in states]))
        for f in dataclasses.fields(WorldState)
    })


def geometry_of(state: WorldState) -> Geometry:
    """The pairwise geometry of `state` (what the world computes after a move)."""
    return Geometry.of(state)


def ring(
    centre: Sequence[float], radius: float, bearings_deg: Sequence[float], theta: float = 0.0, speed: float = 0.0
) -> list[list[float]]:
    """Robot rows [x, y, theta, speed] at `radius` m around `centre`, at the given bearings (degrees)."""
    cx, cy = centre
    return [
        [cx + radius * math.cos(math.radians(a)), cy + radius * math.sin(math.radians(a)), theta, speed]
        for a in bearings_deg
    ]


def far_row(index: int, y: float = 110.0, theta: float = 0.0, speed: float = 0.0) -> list[float]:
    """A robot row parked along y = `y`, 30 m apart per index (out of everyone's way)."""
    return [10.0 + 30.0 * index, y, theta, speed]


def initial_scenario(
    pursuers: Sequence[Sequence[float]],
    evaders: Sequence[Sequence[float]],
    obstacles: Sequence[Sequence[float]] = (),
    vortices: Sequence[Sequence[float]] = (),
    name: str = "hand-made",
    **fields,
) -> Scenario:
    """A scenario whose initial_state fixes every entity (counts follow the lists)."""
    init = InitialState(
        pursuers=rows(pursuers, 4),
        evaders=rows(evaders, 4),
        obstacles=rows(obstacles, 3),
        vortices=rows(vortices, 4),
    )
    return Scenario(
        name=name,
        pursuers=len(init.pursuers),
        evaders=len(init.evaders),
        obstacles=len(init.obstacles),
        vortices=len(init.vortices),
        initial_state=init,
        **fields,
    )


def idle_evader() -> ConstantEvader:
    """Evaders that keep their speed and heading up to drag (a = 0, w = 0)."""
    return ConstantEvader(EVADER_IDLE)


def random_state(
    rng: np.random.Generator,
    num_envs: int,
    num_pursuers: int,
    num_evaders: int,
    num_obstacles: int,
    low: float,
    high: float,
    active_fraction: float = 0.8,
) -> WorldState:
    """B random worlds: positions U(low, high)^2, headings U(0, 2pi), velocities
    independent of the headings (as with a current), obstacle radii U(1.0, 1.1),
    each robot active with probability `active_fraction`."""
    b, n, m, o = num_envs, num_pursuers, num_evaders, num_obstacles

    def xy(k: int) -> np.ndarray:
        return rng.uniform(low, high, size=(b, k, 2))

    return WorldState(
        pursuer_xy=xy(n),
        pursuer_theta=rng.uniform(0, 2 * np.pi, (b, n)),
        pursuer_speed=rng.uniform(0, 3.0, (b, n)),
        pursuer_vel=rng.uniform(-3.0, 3.0, (b, n, 2)),
        pursuer_active=rng.random((b, n)) < active_fraction,
        evader_xy=xy(m),
        evader_theta=rng.uniform(0, 2 * np.pi, (b, m)),
        evader_speed=rng.uniform(0, 3.5, (b, m)),
        evader_vel=rng.uniform(-3.5, 3.5, (b, m, 2)),
        evader_active=rng.random((b, m)) < active_fraction,
        obstacle_xy=xy(o),
        obstacle_r=rng.uniform(1.0, 1.1, (b, o)),
        vortex_xy=np.zeros((b, 0, 2)),
        vortex_gamma=np.zeros((b, 0)),
        vortex_clockwise=np.zeros((b, 0), bool),
        steps=np.zeros(b, np.int64),
    )


def to_ego(theta: float, vec: Sequence[float]) -> np.ndarray:
    """Rot(theta)^T vec: a world vector [2] in the frame of a robot with heading theta."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([c * vec[0] + s * vec[1], -s * vec[0] + c * vec[1]])


def wrap_0_2pi(angle: float) -> float:
    """angle mapped to [0, 2pi)."""
    out = math.fmod(angle, 2 * math.pi)
    if out < 0:
        out += 2 * math.pi
    return 0.0 if out >= 2 * math.pi else out
