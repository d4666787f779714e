"""What a scenario may hold, and the checks that hold it there (world.md sections 11-12): the
limits of its fields, its explicit initial states and the `ScenarioError` a check raises.
terl_rt.sim.scenario's `Scenario` runs `validate` on every scenario it builds.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from terl_rt.sim.evader import UnknownEvader, evader_kind
from terl_rt.sim.params import WorldParams, check_params, short_repr
from terl_rt.sim.reward import REWARD_VARIANTS

if TYPE_CHECKING:
    from terl_rt.sim.scenario import Scenario


class ScenarioError(ValueError):
    """A scenario that is malformed or cannot be placed; the message names the field."""


@dataclass(frozen=True, eq=False)
class InitialState:
    """Explicit initial states; when given, reset draws nothing.

    pursuers [N, 4] and evaders [M, 4]: x (m), y (m), heading (rad), speed (m/s);
    obstacles [O, 3]: x, y, radius (m); vortices [V, 4]: x, y (m), circulation
    Gamma (m^2/s), clockwise (1.0 or 0.0).
    """

    pursuers: np.ndarray
    evaders: np.ndarray
    obstacles: np.ndarray
    vortices: np.ndarray

    def to_dict(self) -> dict[str, list]:
        return {
            "pursuers": self.pursuers.tolist(),
            "evaders": self.evaders.tolist(),
            "obstacles": self.obstacles.tolist(),
            "vortices": [[x, y, g, bool(c)] for x, y, g, c in self.vortices.tolist()],
        }

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, InitialState):
            return NotImplemented
        return all(
            np.array_equal(getattr(self, f.name), getattr(other, f.name))
            for f in dataclasses.fields(self)
        )


# ---------------------------------------------------------------- validation
SCENARIO_LIMITS: dict[str, float] = {
    "arena": 10_000.0,
    "pursuers": 1000,
    "evaders": 500,
    "obstacles": 500,
    "vortices": 500,
    "evader_slots": 256,
    "max_steps": 1_000_000,
    "min_pursuer_evader_init_dis": 10_000.0,
    "clear_r": 10_000.0,
}
"""Largest value of each field: they bound a world's memory and time. A limit can be
raised here for an experiment that needs a bigger world."""
_LOWEST = {"pursuers": 3, "evaders": 1, "obstacles": 0, "vortices": 0, "evader_slots": 1, "max_steps": 1}
MAX_SCENARIO_FILE_BYTES = 4 * 1024 * 1024
"""Largest scenario file `Scenario.from_file` reads (bytes)."""
INITIAL_STATE_MARGIN = 0.5
"""Entities of an initial_state lie within this fraction of the arena's width (height)
outside the arena: x in [-0.5 W, 1.5 W], y in [-0.5 H, 1.5 H]."""
MAX_INITIAL_HEADING = 1000.0
"""rad: headings of an initial_state lie in [-1000, 1000] (they are wrapped into [0, 2 pi);
beyond, the wrap would lose the angle to rounding: 1e300 rad names no direction)."""
_INT_FIELDS = ("pursuers", "evaders", "obstacles", "vortices", "evader_slots", "max_steps")
_FLOAT_FIELDS = ("min_pursuer_evader_init_dis", "clear_r")
STATE_WIDTHS = {"pursuers": 4, "evaders": 4, "obstacles": 3, "vortices": 4}


def limit_hint(name: str) -> str:
    return f"the limit terl_rt.sim.scenario.SCENARIO_LIMITS[{name!r}]; raise it there for a bigger world"


def validate(s: Scenario) -> None:
    if not isinstance(s.name, str) or not s.name or len(s.name) > 200:
        raise ScenarioError(f"name: must be a non-empty string of at most 200 characters, got {short_repr(s.name)}")
    # Tables, logs and CSV files print the name: it must be text that can be written.
    if not s.name.isprintable():  # unpaired surrogates are not printable either
        raise ScenarioError(
            f"name: must be printable text (no control characters or unpaired surrogates), got {short_repr(s.name)}"
        )
    if not isinstance(s.params, WorldParams):
        raise ScenarioError(f"params: must be a WorldParams, got {short_repr(s.params)}")
    problem = check_params(s.params)
    if problem:
        raise ScenarioError(f"params.{problem[0]}: {problem[1]}")
    top = SCENARIO_LIMITS["arena"]
    if (not isinstance(s.arena, (tuple, list)) or len(s.arena) != 2
            or not all(is_number(v) and 0 < v <= top and math.isfinite(v) for v in s.arena)):
        raise ScenarioError(
            f"arena: must be [W, H] with sizes in (0, {top:g}] m ({limit_hint('arena')}), got {short_repr(s.arena)}"
        )
    for name in _INT_FIELDS:
        value = getattr(s, name)
        low = s.params.min_active_pursuers if name == "pursuers" else _LOWEST[name]
        high = SCENARIO_LIMITS[name]
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool):
            raise ScenarioError(f"{name}: must be an integer in [{low}, {high}], got {short_repr(value)}")
        if value < low:
            why = f" (params.min_active_pursuers is {low})" if name == "pursuers" else ""
            raise ScenarioError(f"{name}: must be at least {low}{why}, got {short_repr(value)}")
        if value > high:
            raise ScenarioError(f"{name}: {short_repr(value)} is above {limit_hint(name)}")
    for name in _FLOAT_FIELDS:
        value = getattr(s, name)
        high = SCENARIO_LIMITS[name]
        if not is_number(value) or not 0 <= value <= high or (isinstance(value, float) and not math.isfinite(value)):
            raise ScenarioError(f"{name}: must be a number in [0, {high:g}] m, got {short_repr(value)}")
    if not isinstance(s.reward, str) or s.reward not in REWARD_VARIANTS:
        raise ScenarioError(
            f"reward: must be one of {', '.join(map(repr, REWARD_VARIANTS))}, got {short_repr(s.reward)}"
        )
    try:
        evader_kind(s.evader)
    except UnknownEvader as err:
        raise ScenarioError(f"evader: {err}") from None
    p = s.params
    margins = [("evader_spawn_margin", p.evader_spawn_margin), ("pursuer_spawn_margin", p.pursuer_spawn_margin)]
    if s.obstacles and s.initial_state is None:
        margins.append(("obstacle_spawn_margin", p.obstacle_spawn_margin))
    for name, margin in margins:
        if s.initial_state is None and min(s.arena) < 2 * margin:
            raise ScenarioError(
                f"arena: {s.arena[0]:g} x {s.arena[1]:g} m leaves no room inside params.{name} = {margin:g} m of every wall"
            )
    if s.initial_state is not None:
        if not isinstance(s.initial_state, InitialState):
            raise ScenarioError(f"initial_state: must be an InitialState, got {short_repr(s.initial_state)}")
        validate_initial_state(s)


def validate_initial_state(s: Scenario) -> None:
    init = s.initial_state
    for group, width in STATE_WIDTHS.items():
        rows = getattr(init, group)
        where = f"initial_state.{group}"
        if not isinstance(rows, np.ndarray) or rows.ndim != 2 or rows.shape[1] != width:
            raise ScenarioError(f"{where}: expected rows of {width} numbers, got shape {np.shape(rows)}")
        if not np.all(np.isfinite(rows)):
            raise ScenarioError(f"{where}: holds a non-finite number")
        if len(rows) != getattr(s, group):
            raise ScenarioError(
                f"{group}: is {getattr(s, group)} but initial_state.{group} has {len(rows)} rows"
            )
    p = s.params
    for group, s_max in (("pursuers", p.pursuer_max_speed), ("evaders", p.evader_max_speed)):
        heading = getattr(init, group)[:, 2]
        if np.any(np.abs(heading) > MAX_INITIAL_HEADING):
            row = int(np.flatnonzero(np.abs(heading) > MAX_INITIAL_HEADING)[0])
            raise ScenarioError(
                f"initial_state.{group}[{row}]: heading {heading[row]:.6g} rad; headings must lie in "
                f"[-{MAX_INITIAL_HEADING:g}, {MAX_INITIAL_HEADING:g}] rad"
            )
        speed = getattr(init, group)[:, 3]
        if np.any((speed < 0) | (speed > s_max)):
            raise ScenarioError(f"initial_state.{group}: speeds must lie in [0, {s_max}] m/s")
    if np.any(init.obstacles[:, 2] <= 0) or np.any(init.obstacles[:, 2] > 100):
        raise ScenarioError("initial_state.obstacles: radii must lie in (0, 100] m")
    if np.any(init.vortices[:, 2] < 0) or np.any(init.vortices[:, 2] > 1e4):
        raise ScenarioError("initial_state.vortices: circulation must lie in [0, 10000] m^2/s (direction is the 4th number)")
    if not np.all(np.isin(init.vortices[:, 3], (0.0, 1.0))):
        raise ScenarioError("initial_state.vortices: the 4th number (clockwise) must be true/false or 1/0")
    width, height = s.arena
    lo = np.array([-INITIAL_STATE_MARGIN * width, -INITIAL_STATE_MARGIN * height])
    hi = np.array([(1 + INITIAL_STATE_MARGIN) * width, (1 + INITIAL_STATE_MARGIN) * height])
    for group in STATE_WIDTHS:
        xy = getattr(init, group)[:, :2]
        outside = np.flatnonzero(((xy < lo) | (xy > hi)).any(-1))
        if len(outside):
            i = int(outside[0])
            raise ScenarioError(
                f"initial_state.{group}[{i}]: ({xy[i, 0]:g}, {xy[i, 1]:g}) m is too far outside the {width:g} x {height:g} m "
                f"arena (entities must lie in [{lo[0]:g}, {hi[0]:g}] x [{lo[1]:g}, {hi[1]:g}] m)"
            )
    robots = np.concatenate([init.pursuers[:, :2], init.evaders[:, :2]])
    names = [f"pursuers[{i}]" for i in range(len(init.pursuers))] + [f"evaders[{j}]" for j in range(len(init.evaders))]
    r = p.robot_radius
    if len(robots) > 1:
        distance = np.sqrt(((robots[:, None, :] - robots[None, :, :]) ** 2).sum(-1))
        np.fill_diagonal(distance, np.inf)
        a, b = np.unravel_index(int(np.argmin(distance)), distance.shape)
        if distance[a, b] <= 2 * r:
            a, b = sorted((int(a), int(b)))
            raise ScenarioError(
                f"initial_state: {names[a]} and {names[b]} overlap (centre distance {distance[a, b]:.3g} m, "
                f"robots need more than 2 * robot_radius = {2 * r:.3g} m)"
            )
    if len(robots) and len(init.obstacles):
        distance = np.sqrt(((robots[:, None, :] - init.obstacles[None, :, :2]) ** 2).sum(-1))
        touching = np.argwhere(distance <= r + init.obstacles[None, :, 2])
        if len(touching):
            i, k = (int(v) for v in touching[0])
            raise ScenarioError(
                f"initial_state: {names[i]} is inside or touching obstacles[{k}] (centre distance {distance[i, k]:.3g} m, "
                f"needs more than robot_radius + its radius = {r + init.obstacles[k, 2]:.3g} m)"
            )


def is_number(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
