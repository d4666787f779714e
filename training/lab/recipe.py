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

A recipe that continues a start names the step its steps are counted from, `from_step`; its
first segment continues the start (`python -m training run RECIPE --start START`: a checkpoint,
a snapshot or an exported policy, training.lab.start), and a start at another step shifts every
step of the recipe (the segments' ends, `decay_start`, the curriculum's `curriculum_steps`) by
the difference. The start's network (body and sizes) and the scale of the rewards its values
were learnt in (`reward_scale`) replace the recipe's in every segment (CARRIED_FIELDS), unless the
recipe brings the start's values to a scale of its own first (`start_reward_scale = 1.0`: the
value head's last layer rescaled, training.lab.start.rescale_values):

    from_step = 200_000             # recipes/scale-fine-tune.toml: the default's fine-tune at scale
    [[segment]]
    name = "published"
    steps = 300_000                 # 100 k steps after its start, wherever that is
    refill = true

A recipe may chain others instead: the first K segments of one, then the segments of one that
continues a start, shifted to begin where the first ends (`recipes/terl.toml`):

    [[chain]]
    recipe = "terl-paper.toml"      # a path from this recipe's folder
    segments = 1                    # its first segment only (default: all)
    [[chain]]
    recipe = "scale-fine-tune.toml"

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
import os
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

from training.checkpoint import STATE_FILE, export_checkpoint, read_config, read_counters
from training.config import SECTIONS, Config, ConfigError, read_fields
from training.lab.start import START_FOLDER, StartError, place_start, seed_start
from training.run_lock import holding_run_folder
from training.seed_state import BEST_FOLDER, SeedRun

SEGMENT_KEYS = ("name", "steps", "start", "refill", *SECTIONS)
"""The keys a segment may hold: its name, the step it ends at, where it starts, and config parts."""
STARTS = ("last", "best")
"""What a later segment continues: the previous segment's last checkpoint or its best snapshot."""
RECIPE_KEYS = ("ships", "ships_from", "from_step", "start", "start_reward_scale", "segment")
"""The top-level keys of a recipe of segments."""
CHAIN_KEYS = ("ships", "ships_from", "chain")
"""The top-level keys of a recipe that chains others."""
LINK_KEYS = ("recipe", "segments")
"""The keys of one [[chain]] entry."""
CARRIED_FIELDS = ("model", "hidden", "layers", "heads", "reward_scale")
"""What a start (or a chain's first recipe) gives every segment that continues it: the network's
body and sizes, and the scale of the rewards its values were learnt in (docs/training.md, the
fine-tune at scale: teaching a start's values 20 times its rewards unlearnt it)."""
EXTENSION_KEYS = ("extends", "ships", "ships_from", "start", "start_reward_scale", *SECTIONS)
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
    from_step: int | None = None
    """the step the segments' steps count from, for a recipe that continues a start; None: it
    starts from nothing."""
    start: str | None = None
    """the start it continues unless the command names one (a path from the recipe's folder,
    "{seed}" standing for each seed's number); None: the command must name it."""
    start_reward_scale: float | None = None
    """the reward scale the start's values are brought to before the first segment continues it
    (training.lab.start.rescale_values), which then carries as the start's; None: the start's own carries."""

    def shifted(self, step: int) -> Recipe:
        """The recipe continuing a start at environment step `step`: every step of its segments
        (their ends, decay_start, curriculum_steps) moved by `step - from_step`."""
        if self.from_step is None:
            raise RecipeError(f"{self.path}: starts from nothing; it has no from_step to shift")
        delta = step - self.from_step
        if delta == 0:
            return self
        return dataclasses.replace(self, from_step=step, segments=tuple(
            dataclasses.replace(segment, config=_shift_config(segment.config, delta)) for segment in self.segments
        ))

    def _checked_start(self) -> Recipe:
        """Itself, or RecipeError for a start (or its rescale) in a recipe that starts from nothing."""
        for key in ("start", "start_reward_scale"):
            if getattr(self, key) is not None and self.from_step is None:
                raise RecipeError(f"{self.path}: '{key}' belongs to a recipe that continues a start (with from_step)")
        return self

    def carrying(self, start: Config) -> Recipe:
        """The recipe with the start's CARRIED_FIELDS (its network and reward scale) in every segment."""
        carried = carried_fields(start)
        return dataclasses.replace(self, segments=tuple(
            dataclasses.replace(segment, config=segment.config.replace(**carried)) for segment in self.segments
        ))

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
    known = EXTENSION_KEYS if "extends" in data else CHAIN_KEYS if "chain" in data else RECIPE_KEYS
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise RecipeError(f"{path}: unknown key '{unknown[0]}' (known: {', '.join(known)})")
    if not isinstance(data.get("ships"), str) or not data["ships"].endswith(".onnx"):
        raise RecipeError(f"{path}: 'ships' must name the .onnx file it makes, got {data.get('ships')!r}")
    ships_from = data.get("ships_from", "best")
    if ships_from not in STARTS:
        raise RecipeError(f"{path}: 'ships_from' must be one of {', '.join(STARTS)}, got {ships_from!r}")
    start = data.get("start")
    if start is not None and not isinstance(start, str):
        raise RecipeError(f"{path}: 'start' must be the path of a checkpoint, snapshot or .onnx policy, got {start!r}")
    start = None if start is None else os.path.normpath(path.parent / start)
    start_reward_scale = data.get("start_reward_scale")
    if start_reward_scale is not None and (isinstance(start_reward_scale, bool)
                                           or not isinstance(start_reward_scale, (int, float)) or not start_reward_scale > 0):
        raise RecipeError(f"{path}: 'start_reward_scale' must be a reward scale above 0, got {start_reward_scale!r}")
    start_reward_scale = None if start_reward_scale is None else float(start_reward_scale)
    if "extends" in data:
        extension = _extension(path, data, _extending)
        given = {key: value for key, value in (("start", start), ("start_reward_scale", start_reward_scale)) if value is not None}
        return dataclasses.replace(extension, **given)._checked_start()
    if "chain" in data:
        return _chain(path, data, _extending)
    from_step = data.get("from_step")
    if from_step is not None and (isinstance(from_step, bool) or not isinstance(from_step, int) or from_step < 0):
        raise RecipeError(f"{path}: 'from_step' must be the environment step its steps count from, got {from_step!r}")
    tables = data.get("segment")
    if not isinstance(tables, list) or not tables:
        raise RecipeError(f"{path}: no [[segment]]; a recipe is one or more segments (or 'extends' another)")
    segments: list[Segment] = []
    config = Config()
    for index, table in enumerate(tables, start=1):
        where = f"{path}: segment {index} ({table.get('name', 'unnamed')})"
        segment = _segment(table, config, previous=segments[-1] if segments else None, where=where, from_step=from_step)
        segments.append(segment)
        config = segment.config
    names = [segment.name for segment in segments]
    if len(set(names)) != len(names):
        raise RecipeError(f"{path}: two segments share a name in {names}")
    return Recipe(path, data["ships"], ships_from, tuple(segments), from_step, start, start_reward_scale)._checked_start()


def carried_fields(start: Config) -> dict[str, Any]:
    """The CARRIED_FIELDS of a start's config, by name."""
    return {name: start.value(name) for name in CARRIED_FIELDS}


def _shift_config(config: Config, delta: int) -> Config:
    """`config` with its steps moved by `delta`: the end, the step size's decay start (when it
    decays) and the curriculum's length (when it walks one)."""
    learner, schedule = config.learner, config.schedule
    changes: dict[str, Any] = {"total_steps": schedule.total_steps + delta}
    if learner.final_learning_rate:
        changes["decay_start"] = learner.decay_start + delta
    if schedule.curriculum:
        changes["curriculum_steps"] = (schedule.curriculum_steps or schedule.total_steps) + delta
    return config.replace(**changes)


def _chain(path: Path, data: dict[str, Any], extending: tuple[Path, ...]) -> Recipe:
    """The recipe `data` of file `path` chains: each link's segments (its first `segments`), every
    link after the first continuing where the one before ends, with its CARRIED_FIELDS."""
    links = data["chain"]
    if not isinstance(links, list) or not links:
        raise RecipeError(f"{path}: 'chain' must be one or more [[chain]] tables")
    segments: list[Segment] = []
    first: Recipe | None = None
    for number, link in enumerate(links, start=1):
        where = f"{path}: chain {number}"
        unknown = sorted(set(link) - set(LINK_KEYS)) if isinstance(link, dict) else []
        if not isinstance(link, dict) or not isinstance(link.get("recipe"), str) or unknown:
            raise RecipeError(f"{where}: a link is a table of {', '.join(LINK_KEYS)} with 'recipe' a path, got {link!r}")
        link_path, part = _named_recipe(path, link["recipe"], where, "recipe", extending)
        count = link.get("segments", len(part.segments))
        if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= len(part.segments):
            raise RecipeError(f"{where}: 'segments' must be 1-{len(part.segments)} ({link_path} has "
                              f"{len(part.segments)}), got {count!r}")
        if first is None:
            first = part
        else:
            if part.from_step is None:
                raise RecipeError(f"{where}: {link_path} starts from nothing (no from_step); only the first link may")
            if part.start_reward_scale is not None:
                raise RecipeError(f"{where}: {link_path} brings its start's values to another scale "
                                  "(start_reward_scale), which a chain does not do between links: run it with --start")
            part = part.shifted(segments[-1].config.schedule.total_steps).carrying(segments[-1].config)
        segments.extend(part.segments[:count])
    names = [segment.name for segment in segments]
    if len(set(names)) != len(names):
        raise RecipeError(f"{path}: two segments of the chain share a name in {names}")
    return Recipe(path, data["ships"], data.get("ships_from", "best"), tuple(segments), first.from_step)


def _named_recipe(path: Path, name: str, where: str, key: str, extending: tuple[Path, ...]) -> tuple[Path, Recipe]:
    """The recipe file `path` names under `key` (a path from its folder) and that recipe, read;
    RecipeError (prefixed `where`) for a loop through the recipes being read or a missing file."""
    named = path.parent / name
    if named.resolve() in extending + (path.resolve(),):
        raise RecipeError(f"{where}: '{key}' makes a loop through {named}")
    try:
        return named, load_recipe(named, extending + (path.resolve(),))
    except FileNotFoundError:
        raise RecipeError(f"{where}: '{key}' names {named}, which does not exist") from None


def _extension(path: Path, data: dict[str, Any], extending: tuple[Path, ...]) -> Recipe:
    """The recipe `data` of file `path` describes: its base's segments with its fields in each."""
    if not isinstance(data["extends"], str):
        raise RecipeError(f"{path}: 'extends' must be the path of a recipe, got {data['extends']!r}")
    base_path, base = _named_recipe(path, data["extends"], str(path), "extends", extending)
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
    return Recipe(path, data["ships"], data.get("ships_from", base.ships_from), tuple(segments), base.from_step,
                  base.start, base.start_reward_scale)


def _segment(table: dict[str, Any], base: Config, previous: Segment | None, where: str,
             from_step: int | None = None) -> Segment:
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
    if previous is None and from_step is not None and steps <= from_step:
        raise RecipeError(f"{where}: 'steps' {steps} must lie past the recipe's from_step, {from_step}")
    start = table.get("start", "last")
    if start not in STARTS:
        raise RecipeError(f"{where}: 'start' must be one of {', '.join(STARTS)}, got {start!r}")
    refill = table.get("refill", False)
    if not isinstance(refill, bool):
        raise RecipeError(f"{where}: 'refill' must be true or false, got {refill!r}")
    if previous is None and from_step is None and ("start" in table or "refill" in table):
        raise RecipeError(f"{where}: the first segment starts from nothing; 'start' and 'refill' belong to later ones")
    if previous is None and start != "last":
        raise RecipeError(f"{where}: the first segment continues its start itself; 'start' belongs to later segments")
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


def continuing(recipe: Recipe, out: Path) -> Recipe:
    """`recipe` as the run in `out` (a seed's folder) trains it: shifted to its start's step and
    with its start's network when it continues a start laid down there (training.lab.start), else as
    it is."""
    start = Path(out) / START_FOLDER
    if recipe.from_step is None or not (start / STATE_FILE).is_file():
        return recipe
    return recipe.shifted(read_counters(start).env_step).carrying(read_config(start))


def recipe_finished(recipe: Recipe, out: Path) -> bool:
    """Whether every segment of `recipe` under `out` has ended and its policy is exported."""
    recipe = continuing(recipe, out)
    done = all(finished(segment_folder(out, k, segment), segment) for k, segment in enumerate(recipe.segments, start=1))
    return done and (out / Path(recipe.ships).name).is_file()


def shipped_checkpoint(recipe: Recipe, out: Path) -> Path:
    """The checkpoint of `recipe`'s run under `out` that it ships: the last segment's folder
    (`ships_from = "last"`), else the run's best snapshot, the best/ of the segment that took it
    (a segment continues the best score of the one before it, so a segment that never beat it
    has no best/ of its own)."""
    recipe = continuing(recipe, out)
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
    note: Callable[[str], None] = print, start: str | None = None,
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

    `start` is what the first segment of a recipe with from_step continues (default: the
    recipe's own `start`; a recipe without from_step takes none): a checkpoint, snapshot or .onnx
    policy (training.lab.start), "{seed}" in it replaced by each seed's number. It is laid down in
    each seed's OUT/0-start/ and the recipe shifted to its step, with its CARRIED_FIELDS.
    """
    out = Path(out)
    folders = seed_folders(out, seeds, seed, recipe)
    start = start if start is not None else recipe.start
    if recipe.from_step is not None and start is None:
        raise RecipeError(f"{recipe.path} continues a start (from_step {recipe.from_step:,}): give --start "
                          "CHECKPOINT, SNAPSHOT or POLICY.onnx (\"{seed}\" in it for each seed's own)")
    if recipe.from_step is None and start is not None:
        raise RecipeError(f"{recipe.path} starts from nothing (no from_step), so it takes no --start")
    overrides = {name: value for name, value in (("threads", threads), ("device", device)) if value is not None}
    with ExitStack() as held:
        for folder in folders.values():  # each seed's folder, so stacks of other seeds of a grid may share OUT
            held.enter_context(holding_run_folder(folder))
        if start is not None:
            recipe = _placed_start(recipe, start, folders)
        chosen = recipe.segments[:segments] if segments else recipe.segments
        done = train_segments(recipe, chosen, folders, train, overrides, show_progress, note, started=start is not None)
        failed = sorted(set(folders) - set(done))
        shipped = [] if len(chosen) < len(recipe.segments) else [
            export_checkpoint(shipped_checkpoint(recipe, folders[number]), folders[number] / Path(recipe.ships).name)
            for number in done
        ]
    if failed:
        raise RecipeError(f"seed{'s' if len(failed) > 1 else ''} {', '.join(map(str, failed))} failed (a non-finite "
                          f"loss; the run's output says when); their last checkpoints stay")
    return shipped


def _placed_start(recipe: Recipe, start: str, folders: dict[int, Path]) -> Recipe:
    """Lay down each seed's start in its START_FOLDER; the recipe shifted to their one step, with their network."""
    steps = {}
    for number, folder in folders.items():
        try:
            steps[number] = place_start(seed_start(start, number), folder / START_FOLDER, number,
                                        recipe.start_reward_scale).env_step
        except StartError as error:
            raise RecipeError(f"--start of seed {number}: {error}") from None
    if len(set(steps.values())) > 1:
        raise RecipeError(f"seeds trained together start from one step; their starts are at "
                          f"{', '.join(f'seed {n}: {s:,}' for n, s in steps.items())}: run them apart (--seed S)")
    carried = {number: carried_fields(read_config(folders[number] / START_FOLDER)) for number in folders}
    if len({tuple(fields.values()) for fields in carried.values()}) > 1:
        raise RecipeError(f"seeds trained together share one network and reward scale; their starts have {carried}: "
                          "run them apart")
    return continuing(recipe, next(iter(folders.values())))


def train_segments(recipe: Recipe, segments: Sequence[Segment], folders: dict[int, Path], train: TrainSeeds,
                   overrides: dict[str, int], show_progress: bool, note: Callable[[str], None],
                   started: bool = False) -> list[int]:
    """`run_recipe`'s training: each segment finished, resumed or started in turn for every seed
    (folders: seed -> its run folder), with the run fields `overrides` replaced in every segment's
    config. Seeds that continue from one environment step train together; returns the seeds that
    finished every segment. `started`: the first segment continues each seed's START_FOLDER."""
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
                if index > 1:
                    previous = segment_folder(folders[number], index - 1, recipe.segments[index - 2])
                    source = previous / BEST_FOLDER if segment.start == "best" else previous
                else:
                    source = folders[number] / START_FOLDER if started else None
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
