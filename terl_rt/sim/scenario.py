"""Scenarios: what a world holds, the paper's presets and JSON files (world.md sections 11-12)."""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from terl_rt.sim.params import WorldParams
from terl_rt.sim.reward import REWARD_VARIANTS


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


@dataclass(frozen=True)
class Scenario:
    """One world configuration. Every field but `name` defaults to small-15's value."""

    name: str
    arena: tuple[float, float] = (120.0, 120.0)
    """(W, H) in m: the arena is [0, W] x [0, H]."""
    pursuers: int = 15
    """N: number of pursuers."""
    evaders: int = 4
    """M: number of evaders."""
    obstacles: int = 4
    """number of static disc obstacles."""
    vortices: int = 8
    """number of Rankine vortex cores."""
    evader_slots: int = 8
    """E: evader slots in each pursuer observation."""
    max_steps: int = 1000
    """decision steps before the episode is truncated (0.5 s each)."""
    min_pursuer_evader_init_dis: float = 20.0
    """m: pursuers start more than this from every evader."""
    clear_r: float = 15.0
    """m: start clearance between robots of a kind, and from cores and obstacles."""
    reward: str = "paper"
    """reward variant (world.md section 9): "paper" (the paper's formulas) or "published"
    (what the published trainer optimised). Training only; evaluation metrics ignore it."""
    initial_state: InitialState | None = None
    """explicit initial states (then the counts above are their lengths)."""
    params: WorldParams = field(default_factory=WorldParams)
    """the world's constants."""

    def __post_init__(self) -> None:
        _validate(self)

    # --- construction
    @staticmethod
    def preset(name: str) -> Scenario:
        """The preset called `name` (see `Scenario.presets()`)."""
        if name not in PRESETS:
            raise ScenarioError(
                f"unknown scenario {name!r}; presets are: {', '.join(PRESETS)}"
            )
        return PRESETS[name]

    @staticmethod
    def presets() -> tuple[str, ...]:
        """Names of the presets: the 10 evaluation presets, then the 5 curriculum stages."""
        return tuple(PRESETS)

    @staticmethod
    def from_dict(data: dict[str, Any]) -> Scenario:
        """Build and validate a scenario from its JSON object (world.md section 12)."""
        return _from_dict(data)

    @staticmethod
    def from_file(path: str | Path) -> Scenario:
        """Read a JSON scenario file; errors name the file and the field."""
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except FileNotFoundError:
            raise ScenarioError(f"{path}: no such scenario file") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise ScenarioError(f"{path}: not valid JSON: {err}") from None
        try:
            return _from_dict(data)
        except ScenarioError as err:
            raise ScenarioError(f"{path}: {err}") from None

    # --- serialisation
    def to_dict(self) -> dict[str, Any]:
        """The JSON object of this scenario; `params` holds only non-default constants."""
        out: dict[str, Any] = {
            "name": self.name,
            "arena": list(self.arena),
            "pursuers": self.pursuers,
            "evaders": self.evaders,
            "obstacles": self.obstacles,
            "vortices": self.vortices,
            "evader_slots": self.evader_slots,
            "max_steps": self.max_steps,
            "min_pursuer_evader_init_dis": self.min_pursuer_evader_init_dis,
            "clear_r": self.clear_r,
            "reward": self.reward,
        }
        if self.initial_state is not None:
            out["initial_state"] = self.initial_state.to_dict()
        default = WorldParams()
        changed = {
            name: getattr(self.params, name)
            for name in WorldParams.field_names()
            if getattr(self.params, name) != getattr(default, name)
        }
        if changed:
            out["params"] = changed
        return out

    def to_file(self, path: str | Path) -> None:
        """Write this scenario as a JSON file."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    def replace(self, **changes: Any) -> Scenario:
        """A copy with some fields changed (validated)."""
        return dataclasses.replace(self, **changes)


# ---------------------------------------------------------------- validation
_INT_FIELDS = ("pursuers", "evaders", "obstacles", "vortices", "evader_slots", "max_steps")
_FLOAT_FIELDS = ("min_pursuer_evader_init_dis", "clear_r")
_STATE_WIDTHS = {"pursuers": 4, "evaders": 4, "obstacles": 3, "vortices": 4}


def _validate(s: Scenario) -> None:
    if not isinstance(s.name, str) or not s.name:
        raise ScenarioError("name: must be a non-empty string")
    if len(s.arena) != 2 or not all(_is_number(v) and math.isfinite(v) and v > 0 for v in s.arena):
        raise ScenarioError(f"arena: must be [W, H] with finite positive sizes in m, got {s.arena!r}")
    for name in _INT_FIELDS:
        value = getattr(s, name)
        if not isinstance(value, (int, np.integer)) or isinstance(value, bool):
            raise ScenarioError(f"{name}: must be an integer, got {value!r}")
        if value < 0:
            raise ScenarioError(f"{name}: must be >= 0, got {value}")
    for name in ("evaders", "evader_slots", "max_steps"):
        if getattr(s, name) < 1:
            raise ScenarioError(f"{name}: must be >= 1, got {getattr(s, name)}")
    if s.pursuers < s.params.min_active_pursuers:
        raise ScenarioError(
            f"pursuers: an episode needs at least {s.params.min_active_pursuers}, got {s.pursuers}"
        )
    for name in _FLOAT_FIELDS:
        value = getattr(s, name)
        if not _is_number(value) or not math.isfinite(value) or value < 0:
            raise ScenarioError(f"{name}: must be a finite number >= 0, got {value!r}")
    if s.reward not in REWARD_VARIANTS:
        raise ScenarioError(f"reward: must be one of {', '.join(map(repr, REWARD_VARIANTS))}, got {s.reward!r}")
    if not isinstance(s.params, WorldParams):
        raise ScenarioError("params: must be a WorldParams")
    for name in WorldParams.field_names():
        value = getattr(s.params, name)
        if not _is_number(value) or not math.isfinite(value):
            raise ScenarioError(f"params.{name}: must be a finite number, got {value!r}")
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
        _validate_initial_state(s)


def _validate_initial_state(s: Scenario) -> None:
    init = s.initial_state
    for group, width in _STATE_WIDTHS.items():
        rows = getattr(init, group)
        where = f"initial_state.{group}"
        if rows.ndim != 2 or rows.shape[1] != width:
            raise ScenarioError(f"{where}: expected rows of {width} numbers, got shape {rows.shape}")
        if not np.all(np.isfinite(rows)):
            raise ScenarioError(f"{where}: holds a non-finite number")
        if len(rows) != getattr(s, group):
            raise ScenarioError(
                f"{group}: is {getattr(s, group)} but initial_state.{group} has {len(rows)} rows"
            )
    p = s.params
    for group, s_max in (("pursuers", p.pursuer_max_speed), ("evaders", p.evader_max_speed)):
        speed = getattr(init, group)[:, 3]
        if np.any((speed < 0) | (speed > s_max)):
            raise ScenarioError(f"initial_state.{group}: speeds must lie in [0, {s_max}] m/s")
    if np.any(init.obstacles[:, 2] <= 0):
        raise ScenarioError("initial_state.obstacles: radii must be > 0")
    if np.any(init.vortices[:, 2] < 0):
        raise ScenarioError("initial_state.vortices: circulation must be >= 0 (direction is the 4th number)")
    if not np.all(np.isin(init.vortices[:, 3], (0.0, 1.0))):
        raise ScenarioError("initial_state.vortices: the 4th number (clockwise) must be true/false or 1/0")


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def _from_dict(data: Any) -> Scenario:
    if not isinstance(data, dict):
        raise ScenarioError(f"a scenario must be a JSON object, got {type(data).__name__}")
    known = {f.name for f in dataclasses.fields(Scenario)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ScenarioError(f"{unknown[0]}: unknown field (known: {', '.join(sorted(known))})")
    if "name" not in data:
        raise ScenarioError("name: missing (every scenario needs a name)")
    kwargs = dict(data)
    if "arena" in kwargs:
        arena = kwargs["arena"]
        if not isinstance(arena, (list, tuple)) or len(arena) != 2:
            raise ScenarioError(f"arena: must be [W, H], got {arena!r}")
        kwargs["arena"] = tuple(arena)
    if "params" in kwargs:
        kwargs["params"] = _params_from_dict(kwargs["params"])
    if kwargs.get("initial_state") is not None:
        init = _initial_state_from_dict(kwargs["initial_state"])
        kwargs["initial_state"] = init
        for group in _STATE_WIDTHS:
            kwargs.setdefault(group, len(getattr(init, group)))
    return Scenario(**kwargs)


def _params_from_dict(data: Any) -> WorldParams:
    if not isinstance(data, dict):
        raise ScenarioError("params: must be an object of constant names to numbers")
    unknown = sorted(set(data) - set(WorldParams.field_names()))
    if unknown:
        raise ScenarioError(f"params.{unknown[0]}: unknown constant")
    default = WorldParams()
    for name, value in data.items():
        expected = type(getattr(default, name))
        if not _is_number(value) or (expected is int and not float(value).is_integer()):
            raise ScenarioError(f"params.{name}: must be a {expected.__name__}, got {value!r}")
    return WorldParams(**{k: type(getattr(default, k))(v) for k, v in data.items()})


def _initial_state_from_dict(data: Any) -> InitialState:
    if not isinstance(data, dict):
        raise ScenarioError("initial_state: must be an object with pursuers, evaders, obstacles, vortices")
    unknown = sorted(set(data) - set(_STATE_WIDTHS))
    if unknown:
        raise ScenarioError(f"initial_state.{unknown[0]}: unknown field")
    groups = {}
    for group, width in _STATE_WIDTHS.items():
        rows = data.get(group, [])
        where = f"initial_state.{group}"
        if not isinstance(rows, list):
            raise ScenarioError(f"{where}: must be a list of [{width} numbers] rows")
        for i, row in enumerate(rows):
            if not isinstance(row, list) or len(row) != width:
                raise ScenarioError(f"{where}[{i}]: must be a list of {width} numbers, got {row!r}")
            for column, value in enumerate(row):
                clockwise_flag = group == "vortices" and column == 3 and isinstance(value, bool)
                if not (_is_number(value) or clockwise_flag):
                    raise ScenarioError(f"{where}[{i}]: {value!r} is not a number")
        groups[group] = np.array(rows, dtype=np.float64).reshape(len(rows), width)
    return InitialState(**groups)


# ---------------------------------------------------------------- presets
def _evaluation(name: str, pursuers: int, evaders: int, obstacles: int, size: float, slots: int) -> Scenario:
    # Paper Table III: all 8 vortices, init distance 20, clear_r 15, 1000 steps.
    return Scenario(
        name=name, arena=(size, size), pursuers=pursuers, evaders=evaders,
        obstacles=obstacles, vortices=8, evader_slots=slots, max_steps=1000,
        min_pursuer_evader_init_dis=20.0, clear_r=15.0,
    )


def _curriculum(stage: int, pursuers: int, evaders: int, obstacles: int, vortices: int, init_dis: float) -> Scenario:
    # Training curriculum: arena 120, E = 8, 3000-step episodes.
    return Scenario(
        name=f"curriculum-{stage}", arena=(120.0, 120.0), pursuers=pursuers, evaders=evaders,
        obstacles=obstacles, vortices=vortices, evader_slots=8, max_steps=3000,
        min_pursuer_evader_init_dis=init_dis, clear_r=15.0,
    )


PAPER_SUITE: tuple[str, ...] = (
    "small-11", "small-15", "small-19",
    "medium-48", "medium-51", "medium-56",
    "large-72", "large-76", "large-80",
    "cc-28",
)
"""The 10 evaluation presets of the paper (Table III), in the paper's order."""

CURRICULUM_STARTS: tuple[tuple[int, str], ...] = (
    (0, "curriculum-1"),
    (2_000_000, "curriculum-2"),
    (4_000_000, "curriculum-3"),
    (5_000_000, "curriculum-4"),
    (6_000_000, "curriculum-5"),
)
"""(first environment step, preset name) of each curriculum stage; 7 M steps in all."""

PRESETS: dict[str, Scenario] = {
    s.name: s
    for s in (
        _evaluation("small-11", 11, 3, 2, 120.0, 8),
        _evaluation("small-15", 15, 4, 4, 120.0, 8),
        _evaluation("small-19", 19, 5, 6, 120.0, 8),
        _evaluation("medium-48", 48, 12, 8, 200.0, 14),
        _evaluation("medium-51", 51, 13, 8, 200.0, 14),
        _evaluation("medium-56", 56, 14, 8, 200.0, 14),
        _evaluation("large-72", 72, 18, 8, 220.0, 20),
        _evaluation("large-76", 76, 19, 8, 220.0, 20),
        _evaluation("large-80", 80, 20, 8, 220.0, 20),
        _evaluation("cc-28", 28, 14, 8, 200.0, 12),
        _curriculum(1, 3, 1, 0, 4, 10.0),
        _curriculum(2, 4, 1, 1, 6, 13.0),
        _curriculum(3, 7, 2, 2, 8, 15.0),
        _curriculum(4, 11, 3, 4, 8, 20.0),
        _curriculum(5, 15, 4, 6, 8, 20.0),
    )
}


def curriculum_stage(env_step: int) -> Scenario:
    """The curriculum scenario in force at environment step `env_step` (>= 0)."""
    name = CURRICULUM_STARTS[0][1]
    for start, stage in CURRICULUM_STARTS:
        if env_step >= start:
            name = stage
    return PRESETS[name]
