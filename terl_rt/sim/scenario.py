"""Scenarios: what a world holds, the paper's presets and JSON files (world.md sections 11-12).

The limits of a scenario's fields and their checks are terl_rt.sim.scenario_checks's.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
from dataclasses import dataclass, field
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from terl_rt.sim.evader import DEFAULT_EVADER
from terl_rt.sim.params import WorldParams, check_param, short_repr
from terl_rt.sim.scenario_checks import (
    MAX_SCENARIO_FILE_BYTES, SCENARIO_LIMITS, STATE_WIDTHS, InitialState, ScenarioError, is_number, limit_hint, validate,
)


@dataclass(frozen=True)
class Scenario:
    """One world configuration. Every field but `name` defaults to small-15's value."""

    name: str
    arena: tuple[float, float] = (120.0, 120.0)
    """(W, H) in m: the arena is [0, W] x [0, H]. Valid: each side in (0, 10000], and at
    least twice every spawn margin of `params` when reset draws the entities."""
    pursuers: int = 15
    """N: number of pursuers. Valid: [params.min_active_pursuers, 1000]."""
    evaders: int = 4
    """M: number of evaders. Valid: [1, 500]."""
    obstacles: int = 4
    """number of static disc obstacles. Valid: [0, 500]."""
    vortices: int = 8
    """number of Rankine vortex cores. Valid: [0, 500]."""
    evader_slots: int = 8
    """E: evader slots in each pursuer observation. Valid: [1, 256]."""
    max_steps: int = 1000
    """decision steps before the episode is truncated (0.5 s each). Valid: [1, 1000000]."""
    min_pursuer_evader_init_dis: float = 20.0
    """m: pursuers start more than this from every evader. Valid: [0, 10000]."""
    clear_r: float = 15.0
    """m: start clearance between robots of a kind, and from cores and obstacles. Valid: [0, 10000]."""
    reward: str = "paper"
    """reward variant (world.md section 9): "paper" (the paper's formulas) or "published"
    (what the published trainer optimised). Training only; evaluation metrics ignore it."""
    evader: str = DEFAULT_EVADER
    """how the evaders behave: a name of terl_rt.sim.evader.EVADERS (`terl-rt scenarios --evaders`),
    "apf" (the paper's potential field), "still" or "widest-gap" (docs/simulator.md). A file
    holds it only when it is not "apf"."""
    initial_state: InitialState | None = None
    """explicit initial states (then the counts above are their lengths). Valid: no two
    robots overlap (centre distance > 2 robot_radius), no robot touches an obstacle (centre
    distance > robot_radius + obstacle radius), every entity within INITIAL_STATE_MARGIN
    times the arena's size of the arena, speeds in [0, s_max], obstacle radii in (0, 100]."""
    params: WorldParams = field(default_factory=WorldParams)
    """the world's constants; each has its valid range in its docstring (PARAM_RANGES)."""

    def __post_init__(self) -> None:
        validate(self)

    # --- construction
    @staticmethod
    def preset(name: str) -> Scenario:
        """The preset called `name` (see `Scenario.presets()`)."""
        if name not in PRESETS:
            raise ScenarioError(f"unknown scenario {short_repr(name)}{did_you_mean(str(name), PRESETS)}; `terl-rt scenarios` (Scenario.presets()) lists the presets")
        return PRESETS[name]

    @staticmethod
    def presets() -> tuple[str, ...]:
        """Names of the presets: the 10 evaluation presets of the paper's table, the 3 of the
        authors' released small-scale evaluation config, then the 5 curriculum stages."""
        return tuple(PRESETS)

    @staticmethod
    def from_dict(data: dict[str, Any]) -> Scenario:
        """Build and validate a scenario from its JSON object (world.md section 12)."""
        return _from_dict(data)

    @staticmethod
    def from_file(path: str | Path) -> Scenario:
        """Read a JSON scenario file; errors name the file and the field.

        The file must be a regular file of at most MAX_SCENARIO_FILE_BYTES holding one
        JSON object without duplicate keys."""
        path = Path(path)
        if not path.exists():
            raise ScenarioError(f"{path}: no such scenario file")
        if path.is_dir():
            raise ScenarioError(f"{path}: is a folder, not a scenario file")
        if not path.is_file():
            raise ScenarioError(f"{path}: not a regular file (a device or a pipe), not a scenario file")
        size = path.stat().st_size
        if size > MAX_SCENARIO_FILE_BYTES:
            raise ScenarioError(
                f"{path}: {size:,} bytes, above the limit of {MAX_SCENARIO_FILE_BYTES:,} "
                "(terl_rt.sim.scenario.MAX_SCENARIO_FILE_BYTES)"
            )
        try:
            with open(path, "rb") as handle:
                text = handle.read(MAX_SCENARIO_FILE_BYTES + 1).decode("utf-8")
        except UnicodeDecodeError as err:
            raise ScenarioError(f"{path}: not valid JSON: {err}") from None
        try:
            data = loads_json(text)
        except ScenarioError as err:
            raise ScenarioError(f"{path}: {err}") from None
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
        if self.evader != DEFAULT_EVADER:
            out["evader"] = self.evader
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

    @property
    def label(self) -> str:
        """The name, with the evader where it is not the default (`scenario_label`)."""
        return scenario_label(self.name, self.evader)


def scenario_label(name: str, evader: str) -> str:
    """How results name a scenario: "small-15" with the paper's evader, "small-15/widest-gap"
    with another."""
    return name if evader == DEFAULT_EVADER else f"{name}/{evader}"


# ---------------------------------------------------------------- scenario files
def did_you_mean(name: str, known: Iterable[str]) -> str:
    """" (did you mean 'x'?)" naming the known name closest to `name` (difflib's ratio
    >= 0.6), or "" when none is close."""
    close = difflib.get_close_matches(name, list(known), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _key(key: Any) -> str:
    """A field name for an error line, cut to 60 characters."""
    text = str(key)
    return text if len(text) <= 60 else text[:57] + "..."


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    seen: dict[str, Any] = {}
    for key, value in pairs:
        if key in seen:
            raise ScenarioError(f"{_key(key)}: the key appears twice in one JSON object")
        seen[key] = value
    return seen


def _bounded_int(text: str) -> int:
    if len(text.lstrip("-")) > 30:
        raise ScenarioError(f"a {len(text)}-digit integer ({short_repr(text)}); numbers of a scenario are far smaller")
    return int(text)


def _bounded_float(text: str) -> float:
    if len(text) > 400:
        raise ScenarioError(f"a {len(text)}-character number ({short_repr(text)}); numbers of a scenario are far shorter")
    return float(text)


def loads_json(text: str) -> Any:
    """Parse scenario JSON: duplicate keys, absurdly long numbers and nesting too deep for
    the parser are a ScenarioError, as is any syntax error."""
    try:
        return json.loads(text, object_pairs_hook=_no_duplicates, parse_int=_bounded_int, parse_float=_bounded_float)
    except json.JSONDecodeError as err:
        raise ScenarioError(f"not valid JSON: {err}") from None
    except RecursionError:
        raise ScenarioError("not valid JSON for a scenario: nested too deeply") from None
    except ValueError as err:  # int/float conversions
        raise ScenarioError(f"not valid JSON: {short_repr(str(err), 120)}") from None


def _from_dict(data: Any) -> Scenario:
    if not isinstance(data, dict):
        raise ScenarioError(f"a scenario must be a JSON object, got {type(data).__name__}")
    known = {f.name for f in dataclasses.fields(Scenario)}
    unknown = sorted(set(map(str, data)) - known)
    if unknown:
        raise ScenarioError(
            f"{_key(unknown[0])}: unknown field{did_you_mean(unknown[0], known)} (known: {', '.join(sorted(known))})"
        )
    if "name" not in data:
        raise ScenarioError("name: missing (every scenario needs a name)")
    kwargs = dict(data)
    if "arena" in kwargs:
        arena = kwargs["arena"]
        if not isinstance(arena, (list, tuple)) or len(arena) != 2:
            raise ScenarioError(f"arena: must be [W, H], got {short_repr(arena)}")
        kwargs["arena"] = tuple(arena)
    if "params" in kwargs:
        kwargs["params"] = _params_from_dict(kwargs["params"])
    if kwargs.get("initial_state") is not None:
        init = _initial_state_from_dict(kwargs["initial_state"])
        kwargs["initial_state"] = init
        for group in STATE_WIDTHS:
            kwargs.setdefault(group, len(getattr(init, group)))
    return Scenario(**kwargs)


def _params_from_dict(data: Any) -> WorldParams:
    if not isinstance(data, dict):
        raise ScenarioError("params: must be an object of constant names to numbers")
    unknown = sorted(set(map(str, data)) - set(WorldParams.field_names()))
    if unknown:
        raise ScenarioError(
            f"params.{_key(unknown[0])}: unknown constant{did_you_mean(unknown[0], WorldParams.field_names())}; "
            "the constants are the fields of terl_rt.WorldParams"
        )
    default = WorldParams()
    for name, value in data.items():
        problem = check_param(name, value)
        if problem:
            raise ScenarioError(f"params.{name}: {problem}")
    return WorldParams(**{k: type(getattr(default, k))(v) for k, v in data.items()})


def _initial_state_from_dict(data: Any) -> InitialState:
    if not isinstance(data, dict):
        raise ScenarioError("initial_state: must be an object with pursuers, evaders, obstacles, vortices")
    unknown = sorted(set(data) - set(STATE_WIDTHS))
    if unknown:
        raise ScenarioError(f"initial_state.{_key(unknown[0])}: unknown field{did_you_mean(str(unknown[0]), STATE_WIDTHS)}")
    groups = {}
    for group, width in STATE_WIDTHS.items():
        rows = data.get(group, [])
        where = f"initial_state.{group}"
        if not isinstance(rows, list):
            raise ScenarioError(f"{where}: must be a list of [{width} numbers] rows")
        limit = SCENARIO_LIMITS[group]
        if len(rows) > limit:
            raise ScenarioError(f"{where}: {len(rows)} rows, above {limit_hint(group)}")
        for i, row in enumerate(rows):
            if not isinstance(row, list) or len(row) != width:
                raise ScenarioError(f"{where}[{i}]: must be a list of {width} numbers, got {short_repr(row)}")
            for column, value in enumerate(row):
                clockwise_flag = group == "vortices" and column == 3 and isinstance(value, bool)
                if not (is_number(value) or clockwise_flag):
                    raise ScenarioError(f"{where}[{i}]: {short_repr(value)} is not a number")
                if not isinstance(value, bool) and isinstance(value, int) and abs(value) > 1e15:
                    raise ScenarioError(f"{where}[{i}]: {short_repr(value)} is far outside any world")
        groups[group] = np.array(rows, dtype=np.float64).reshape(len(rows), width)
    return InitialState(**groups)


# ---------------------------------------------------------------- presets
def _evaluation(name: str, pursuers: int, evaders: int, obstacles: int, size: float, slots: int) -> Scenario:
    # Paper Table III (and the released small config): all 8 vortices, init distance 20,
    # clear_r 15, 1000 steps.
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

PUBLISHED_SMALL_SUITE: tuple[str, ...] = ("small-published-7", "small-published-11", "small-published-15")
"""The small-scale evaluation config the authors released with their code (policy.md
section 2): 7 / 11 / 15 pursuers with 2 / 3 / 4 evaders and 2 / 4 / 6 obstacles, not the
table's 11 / 15 / 19; the rest (arena 120, E = 8, 8 vortices, 1000 steps) is small scale's."""

CURRICULUM_STARTS: tuple[tuple[int, str], ...] = (
    (0, "curriculum-1"),
    (2_000_000, "curriculum-2"),
    (4_000_000, "curriculum-3"),
    (5_000_000, "curriculum-4"),
    (6_000_000, "curriculum-5"),
)
"""(first environment step, preset name) of each curriculum stage; 7 M steps in all."""
CURRICULUM_STEPS = 7_000_000
"""Environment steps of the published curriculum."""

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
        _evaluation("small-published-7", 7, 2, 2, 120.0, 8),
        _evaluation("small-published-11", 11, 3, 4, 120.0, 8),
        _evaluation("small-published-15", 15, 4, 6, 120.0, 8),
        _curriculum(1, 3, 1, 0, 4, 10.0),
        _curriculum(2, 4, 1, 1, 6, 13.0),
        _curriculum(3, 7, 2, 2, 8, 15.0),
        _curriculum(4, 11, 3, 4, 8, 20.0),
        _curriculum(5, 15, 4, 6, 8, 20.0),
    )
}


def curriculum_stage(env_step: int, curriculum_steps: int = CURRICULUM_STEPS) -> Scenario:
    """The curriculum scenario in force at environment step `env_step` (>= 0) of a curriculum
    of `curriculum_steps` steps: each stage starts at its published fraction of them (2/7, 4/7,
    5/7, 6/7), rounded to the nearest step; after them the last stage goes on."""
    name = CURRICULUM_STARTS[0][1]
    for start, stage in CURRICULUM_STARTS:
        if env_step >= int(round(start / CURRICULUM_STEPS * curriculum_steps)):
            name = stage
    return PRESETS[name]
