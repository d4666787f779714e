"""Recipes: how a shipped policy is made, as one TOML file, and the runner that makes it.

A recipe (recipes/<policy>.toml) is an ordered list of segments. Each names the environment
step it ends at and only the config fields it changes, by part (training.config): the first
segment changes the defaults, each later one the segment before it, and continues that
segment's network, optimizer, counters and replay buffer (a fine-tune when it changes fields).

    ships = "exported/terl.onnx"    # the file it makes (a path of the repository)

    [[segment]]
    name = "curriculum"             # the segment's folder: OUT/1-curriculum/
    steps = 200_000                 # environment step it ends at
    [segment.network]
    hidden = 64

    [[segment]]
    name = "medium"
    steps = 350_000
    start = "best"                  # continue the previous segment's best snapshot (default "last")
    refill = true                   # refill the replay buffer instead of loading the saved one
    [segment.schedule]
    curriculum = false
    scenario = "medium-48"

A recipe may instead extend another (a path relative to its own folder) and change fields in
every segment of it: its parts' fields replace the base's in each segment, over the base's own
values; the segments, their names, steps and starts are the base's. It names the file it ships;
`ships_from` is the base's unless it gives one. The comparison's recipes are terl-paper's this way:

    extends = "../terl-paper.toml"
    ships = "exported/comparison/iqn.onnx"
    [network]                       # in every segment: the body of the method
    model = "iqn"
    layers = 0
    heads = 0

`run_recipe` trains the segments in order into OUT/<k>-<name>/ and exports the run's best
snapshot (or the last segment's last checkpoint: `ships_from = "last"`) as OUT/<stem of
ships>.onnx. A recipe cut off (a killed run, a lost machine) runs again with the same command:
finished segments are skipped and a segment with a checkpoint is resumed from it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import shutil
import sys
from contextlib import ExitStack

if sys.version_info >= (3, 11):
    import tomllib
else:  # Python 3.10: the same parser, from PyPI (the train extra installs it there)
    import tomli as tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from training.checkpoint import STATE_FILE, export_checkpoint, read_counters
from training.config import SECTIONS, Config, ConfigError, read_fields
from training.run_lock import holding_run_folder
from training.train import BEST_FOLDER, SeedRun

SEGMENT_KEYS = ("name", "steps", "start", "refill", *SECTIONS)
"""The keys a segment may hold: its name, the step it ends at, where it starts, and config parts."""
STARTS = ("last", "best")
"""What a later segment continues: the previous segment's last checkpoint or its best snapshot."""
RECIPE_KEYS = ("ships", "ships_from", "segment")
"""The top-level keys of a recipe of segments."""
EXTENSION_KEYS = ("extends", "ships", "ships_from", *SECTIONS)
"""The top-level keys of a recipe that extends another."""


class RecipeError(ConfigError):
    """A recipe that is malformed; the message names the file and the segment."""


@dataclass(frozen=True)
class Segment:
    """One stretch of training under one config."""

    name: str
    """the segment's name, also its folder's (OUT/<k>-<name>)."""
    config: Config
    """the whole config it trains under (its schedule's total_steps: the step it ends at)."""
    start: str
    """"last" or "best": which checkpoint of the previous segment it continues (unused by the first)."""
    refill: bool
    """refill the replay buffer instead of loading the previous segment's saved one."""


@dataclass(frozen=True)
class Recipe:
    """A shipped policy's recipe: what it ships as and its segments in order."""

    path: Path
    ships: str
    """the policy file it makes, as the repository names it (e.g. exported/terl.onnx)."""
    ships_from: str
    """"best" or "last": which checkpoint of the last segment is exported."""
    segments: tuple[Segment, ...]

    @property
    def sha256(self) -> str:
        """Hex SHA-256 of the recipe file (a model card names the recipe by path and hash)."""
        return hashlib.sha256(self.path.read_bytes()).hexdigest()

    @property
    def notes(self) -> list[str]:
        """The recipe's own account of itself, its leading comment lines without their "# "
        (what it follows, where it differs): a model card quotes them."""
        lines = []
        for line in self.path.read_text().splitlines():
            if not line.startswith("#"):
                break
            lines.append(line[2:] if line.startswith("# ") else line[1:])
        return lines


def load_recipe(path: str | Path, _extending: tuple[Path, ...] = ()) -> Recipe:
    """Read and check a recipe file (and the recipe it extends); RecipeError names the file, the
    segment and the key at fault."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: no such recipe") from None
    except tomllib.TOMLDecodeError as error:
        raise RecipeError(f"{path}: not valid TOML: {error}") from None
    known = EXTENSION_KEYS if "extends" in data else RECIPE_KEYS
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise RecipeError(f"{path}: unknown key '{unknown[0]}' (known: {', '.join(known)})")
    if not isinstance(data.get("ships"), str) or not data["ships"].endswith(".onnx"):
        raise RecipeError(f"{path}: 'ships' must name the .onnx file it makes, got {data.get('ships')!r}")
    ships_from = data.get("ships_from", "best")
    if ships_from not in STARTS:
        raise RecipeError(f"{path}: 'ships_from' must be one of {', '.join(STARTS)}, got {ships_from!r}")
    if "extends" in data:
        return _extension(path, data, _extending)
    tables = data.get("segment")
    if not isinstance(tables, list) or not tables:
        raise RecipeError(f"{path}: no [[segment]]; a recipe is one or more segments (or 'extends' another)")
    segments: list[Segment] = []
    config = Config()
    for index, table in enumerate(tables, start=1):
        where = f"{path}: segment {index} ({table.get('name', 'unnamed')})"
        segment = _segment(table, config, previous=segments[-1] if segments else None, where=where)
        segments.append(segment)
        config = segment.config
    names = [segment.name for segment in segments]
    if len(set(names)) != len(names):
        raise RecipeError(f"{path}: two segments share a name in {names}")
    return Recipe(path, data["ships"], ships_from, tuple(segments))


def _extension(path: Path, data: dict[str, Any], extending: tuple[Path, ...]) -> Recipe:
    """The recipe `data` of file `path` describes: its base's segments with its fields in each."""
    if not isinstance(data["extends"], str):
        raise RecipeError(f"{path}: 'extends' must be the path of a recipe, got {data['extends']!r}")
    base_path = path.parent / data["extends"]
    if base_path.resolve() in extending + (path.resolve(),):
        raise RecipeError(f"{path}: 'extends' makes a loop through {base_path}")
    try:
        base = load_recipe(base_path, extending + (path.resolve(),))
    except FileNotFoundError:
        raise RecipeError(f"{path}: 'extends' names {base_path}, which does not exist") from None
    changes = read_fields({section: data[section] for section in SECTIONS if section in data}, source=str(path))
    if "total_steps" in changes:
        raise RecipeError(f"{path}: the steps are the segments' of {base_path}; schedule.total_steps cannot change")
    segments = []
    for index, segment in enumerate(base.segments, start=1):
        try:
            config = segment.config.replace(**changes)
        except ConfigError as error:
            raise RecipeError(f"{path}: in segment {index} ({segment.name}) of {base_path}: {error}") from None
        segments.append(dataclasses.replace(segment, config=config))
    return Recipe(path, data["ships"], data.get("ships_from", base.ships_from), tuple(segments))


def _segment(table: dict[str, Any], base: Config, previous: Segment | None, where: str) -> Segment:
    unknown = sorted(set(table) - set(SEGMENT_KEYS))
    if unknown:
        raise RecipeError(f"{where}: unknown key '{unknown[0]}' (known: {', '.join(SEGMENT_KEYS)})")
    name, steps = table.get("name"), table.get("steps")
    if not isinstance(name, str) or not name or not all(c.isalnum() or c in "-_." for c in name):
        raise RecipeError(f"{where}: 'name' must be a word of letters, digits, '-', '_' or '.', got {name!r}")
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise RecipeError(f"{where}: 'steps' must be a positive whole number of environment steps, got {steps!r}")
    if previous is not None and steps <= previous.config.schedule.total_steps:
        raise RecipeError(
            f"{where}: 'steps' {steps} must lie past the previous segment's end, {previous.config.schedule.total_steps}"
        )
    start = table.get("start", "last")
    if start not in STARTS:
        raise RecipeError(f"{where}: 'start' must be one of {', '.join(STARTS)}, got {start!r}")
    refill = table.get("refill", False)
    if not isinstance(refill, bool):
        raise RecipeError(f"{where}: 'refill' must be true or false, got {refill!r}")
    if previous is None and ("start" in table or "refill" in table):
        raise RecipeError(f"{where}: the first segment starts from nothing; 'start' and 'refill' belong to later ones")
    changes = {section: table[section] for section in SECTIONS if section in table}
    for section, fields in changes.items():
        if "total_steps" in fields:
            raise RecipeError(f"{where}: give the segment's end as 'steps', not schedule.total_steps")
    try:
        config = base.replace(**read_fields(changes, source=where), total_steps=steps)
    except ConfigError as error:
        message = str(error)
        raise RecipeError(message if message.startswith(where) else f"{where}: {message}") from None
    return Segment(name, config, start, refill)


def segment_folder(out: Path, index: int, segment: Segment) -> Path:
    """Where segment `index` (from 1) trains: OUT/<index>-<name>."""
    return out / f"{index}-{segment.name}"


def finished(folder: Path, segment: Segment) -> bool:
    """Whether `folder` holds the segment's last checkpoint."""
    return (folder / STATE_FILE).is_file() and read_counters(folder).env_step >= segment.config.schedule.total_steps


def recipe_finished(recipe: Recipe, out: Path) -> bool:
    """Whether every segment of `recipe` under `out` has ended and its policy is exported."""
    done = all(finished(segment_folder(out, k, segment), segment) for k, segment in enumerate(recipe.segments, start=1))
    return done and (out / Path(recipe.ships).name).is_file()


def shipped_checkpoint(recipe: Recipe, out: Path) -> Path:
    """The checkpoint of `recipe`'s run under `out` that it ships: the last segment's folder
    (`ships_from = "last"`), else the run's best snapshot, the best/ of the segment that took it
    (a segment continues the best score of the one before it, so a segment that never beat it
    has no best/ of its own)."""
    last = segment_folder(out, len(recipe.segments), recipe.segments[-1])
    if recipe.ships_from == "last":
        return last
    best_step = read_counters(last).best_step
    for k, segment in reversed(list(enumerate(recipe.segments, start=1))):
        best = segment_folder(out, k, segment) / BEST_FOLDER
        if (best / STATE_FILE).is_file() and read_counters(best).env_step == best_step:
            return best
    raise FileNotFoundError(f"{out}: no best/ snapshot of step {best_step} in any segment folder")


TrainSeeds = Callable[..., dict[int, Any]]
"""training.train.train_seeds, or a stand-in with its signature (config, runs, show_progress=True,
load_replay=True) -> {seed: counters} of the seeds that finished."""


def seed_folders(out: Path, seeds: Sequence[int] | None, seed: int | None, recipe: Recipe) -> dict[int, Path]:
    """Where each seed of a run trains: OUT itself for one seed (`seed`, else the recipe's), or
    OUT/seed-<S> for each of `seeds` (seeds trained together)."""
    if seeds is None:
        return {seed if seed is not None else recipe.segments[0].config.run.seed: out}
    if not seeds or len(set(seeds)) != len(seeds):
        raise RecipeError(f"the seeds {list(seeds)} must be one or more, none repeated")
    return {number: out / f"seed-{number}" for number in seeds}


def run_recipe(
    recipe: Recipe, out: str | Path, train: TrainSeeds, threads: int | None = None, seed: int | None = None,
    seeds: Sequence[int] | None = None, device: str | None = None, segments: int | None = None, show_progress: bool = True,
    note: Callable[[str], None] = print,
) -> list[Path]:
    """Train every segment of `recipe` not yet finished under `out`, then export the policy it
    ships; returns the .onnx paths (OUT/<stem of ships>.onnx, or with `seeds`
    OUT/seed-<S>/<stem of ships>.onnx, one a seed that finished).

    A segment with a checkpoint but short of its end is resumed from it; one without is started
    (its folder emptied first, so its metrics.jsonl holds one run), from nothing or from the
    previous segment's `start` checkpoint. `threads` replaces every segment's run.threads (torch
    threads are set by the caller from the returned configs: see `python -m training run`), and
    `device` every segment's learner.device;
    `seed` replaces every segment's run.seed (a later segment continues the generators of the one
    before it, so the seed acts where the first starts). `seeds` trains several seeds together,
    each in OUT/seed-<S> as a one-seed run lays out OUT; a seed that fails stops alone and
    RecipeError names it once the others are done. `segments` trains the first so many segments
    only (nothing is exported unless they are all of them). The run holds each seed's folder
    throughout (training.run_lock): another run on one raises RunFolderHeld before anything is written.
    """
    out = Path(out)
    folders = seed_folders(out, seeds, seed, recipe)
    overrides = {name: value for name, value in (("threads", threads), ("device", device)) if value is not None}
    chosen = recipe.segments[:segments] if segments else recipe.segments
    with ExitStack() as held:
        for folder in folders.values():  # each seed's folder, so stacks of other seeds of a grid may share OUT
            held.enter_context(holding_run_folder(folder))
        done = train_segments(recipe, chosen, folders, train, overrides, show_progress, note)
        failed = sorted(set(folders) - set(done))
        shipped = [] if len(chosen) < len(recipe.segments) else [
            export_checkpoint(shipped_checkpoint(recipe, folders[number]), folders[number] / Path(recipe.ships).name)
            for number in done
        ]
    if failed:
        raise RecipeError(f"seed{'s' if len(failed) > 1 else ''} {', '.join(map(str, failed))} failed (a non-finite "
                          f"loss; the run's output says when); their last checkpoints stay")
    return shipped


def train_segments(recipe: Recipe, segments: Sequence[Segment], folders: dict[int, Path], train: TrainSeeds,
                   overrides: dict[str, int], show_progress: bool, note: Callable[[str], None]) -> list[int]:
    """`run_recipe`'s training: each segment finished, resumed or started in turn for every seed
    (folders: seed -> its run folder), with the run fields `overrides` replaced in every segment's
    config. Seeds that continue from one environment step train together; returns the seeds that
    finished every segment."""
    alive = list(folders)
    for index, segment in enumerate(segments, start=1):
        config = segment.config.replace(**overrides)
        label = f"segment {index}/{len(recipe.segments)} ({segment.name}, to {config.schedule.total_steps:,} steps)"
        groups: dict[tuple[int, bool], list[SeedRun]] = {}
        for number in alive:
            folder = segment_folder(folders[number], index, segment)
            named = label if len(folders) == 1 else f"seed {number}, {label}"
            if finished(folder, segment):
                note(f"{named}: finished, in {folder}")
                continue
            if (folder / STATE_FILE).is_file():
                note(f"{named}: resuming its checkpoint in {folder}")
                source, load_replay = folder, True
            else:
                if folder.exists():
                    shutil.rmtree(folder)
                previous = segment_folder(folders[number], index - 1, recipe.segments[index - 2]) if index > 1 else None
                source = None if previous is None else (previous / BEST_FOLDER if segment.start == "best" else previous)
                note(f"{named}: starting" + ("" if source is None else f" from {source}"))
                load_replay = not segment.refill
            # seeds that continue from one step train together (a missing checkpoint is train's to name)
            step = read_counters(source).env_step if source is not None and (source / STATE_FILE).is_file() else 0
            groups.setdefault((step, load_replay), []).append(SeedRun(number, folder, source))
        for (_, load_replay), runs in groups.items():
            seed_config = config if len(folders) > 1 else config.replace(seed=runs[0].seed)
            finished_seeds = train(seed_config, runs, show_progress=show_progress, load_replay=load_replay)
            alive = [number for number in alive if number in finished_seeds or number not in {run.seed for run in runs}]
    return alive
