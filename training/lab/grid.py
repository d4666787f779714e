"""A method x seed grid of recipes, each cell a run of its own: `python -m training run RECIPE
--out OUT/<method>/seed-<S> --seed S --threads 1` in a process of its own, on this machine or
as a Ray task (training.lab.grid_ray), its output in OUT/<method>/seed-<S>.log. With seeds trained
together (`stack_cells`), a process trains several seeds of a method (`run --seeds`), each in its
own cell folder, its output in OUT/<method>/seeds-<S>-<S>....log.

A method is a recipe's file stem (recipes/comparison/iqn.toml: iqn). A cell is resumable as
its recipe is: the grid run again skips the cells that have finished and starts the others,
which go on from their last checkpoints. A cell that fails is reported in one line and the
others go on; SIGINT or SIGTERM is passed to every running cell once, so each writes a whole
checkpoint before it ends (training.stops), and no new cell starts.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from training.lab.recipe import Recipe, RecipeError, load_recipe, recipe_finished
from training.run_lock import RUN_HELD

RUN_PROGRAM = ("-m", "training", "run")
"""The Python arguments that run one cell's recipe (the cell's own arguments follow)."""
STOPPED = 130
"""Exit status of a cell stopped by a signal after writing its checkpoint (training.__main__)."""
POLL_S = 0.2
"""Seconds between looks at the running cells."""


@dataclass(frozen=True)
class Cell:
    """One seed of one method: a recipe's run under its own folder."""

    method: str
    """the recipe's file stem (e.g. iqn): the name of its folder and of its shipped files."""
    seed: int
    """the run's seed (RunConfig.seed of every segment)."""
    recipe: Path
    """the recipe file."""
    out: Path
    """the run's folder: GRID_OUT/<method>/seed-<seed>."""
    device: str | None = None
    """torch device of the run's updates (`run --device`; None: the recipe's)."""

    @property
    def name(self) -> str:
        """The cell as progress lines name it: "iqn seed 2"."""
        return f"{self.method} seed {self.seed}"

    @property
    def log(self) -> Path:
        """The cell's stdout and stderr, every attempt appended: GRID_OUT/<method>/seed-<seed>.log."""
        return self.out.with_name(f"{self.out.name}.log")

    def logs(self) -> list[Path]:
        """The logs of the cell's runs that exist: its own (`log`), then those of the stacks it
        trained in (`CellStack.log`: GRID_OUT/<method>/seeds-<S>-<S>....log naming its seed)."""
        stacks = sorted(path for path in self.out.parent.glob("seeds-*.log")
                        if str(self.seed) in path.stem.removeprefix("seeds-").split("-"))
        return [path for path in (self.log, *stacks) if path.is_file()]

    def arguments(self) -> list[str]:
        """The arguments of `python -m training run` (after RUN_PROGRAM) that make this cell."""
        device = [] if self.device is None else ["--device", self.device]
        return [str(self.recipe), "--out", str(self.out), "--seed", str(self.seed), "--threads", "1", "--quiet", *device]

    def finished(self, recipe: Recipe) -> bool:
        """Whether the cell's run has ended and its policy is exported."""
        return recipe_finished(recipe, self.out)


@dataclass(frozen=True)
class CellStack:
    """Seeds of one method trained together in one process (`python -m training run --seeds`):
    each seed's run in its own cell folder, as a cell of its own would lay it out."""

    cells: tuple[Cell, ...]
    """the seeds' cells, one method, in seed order."""

    @property
    def method(self) -> str:
        return self.cells[0].method

    @property
    def name(self) -> str:
        """The stack as progress lines name it: "iqn seeds 1,2,3"."""
        return f"{self.method} seeds {','.join(str(cell.seed) for cell in self.cells)}"

    @property
    def log(self) -> Path:
        """The stack's stdout and stderr: GRID_OUT/<method>/seeds-<S>-<S>....log."""
        return self.cells[0].out.with_name(f"seeds-{'-'.join(str(cell.seed) for cell in self.cells)}.log")

    def arguments(self) -> list[str]:
        """The arguments of `python -m training run` (after RUN_PROGRAM) that train the stack: its
        seeds land in GRID_OUT/<method>/seed-<S>, the cells' own folders."""
        seeds = ",".join(str(cell.seed) for cell in self.cells)
        device = [] if self.cells[0].device is None else ["--device", self.cells[0].device]
        return [str(self.cells[0].recipe), "--out", str(self.cells[0].out.parent), "--seeds", seeds, "--threads", "1",
                "--quiet", *device]

    def finished(self, recipe: Recipe) -> bool:
        """Whether every seed of the stack has ended and exported its policy."""
        return all(cell.finished(recipe) for cell in self.cells)


def stack_cells(cells: Sequence[tuple[Cell, Recipe]], seeds_per_process: int) -> list[tuple[Cell | CellStack, Recipe]]:
    """The grid's cells to run, `seeds_per_process` seeds of a method a process (1: every cell
    alone): each method's unfinished cells in seed order, in stacks of at most that many (the
    finished cells stay as they are)."""
    if seeds_per_process == 1:
        return list(cells)
    by_method: dict[str, list[tuple[Cell, Recipe]]] = {}
    stacks: list[tuple[Cell | CellStack, Recipe]] = []
    for cell, recipe in cells:
        if cell.finished(recipe):
            stacks.append((cell, recipe))  # run_grid reports it finished
        else:
            by_method.setdefault(cell.method, []).append((cell, recipe))
    for method_cells in by_method.values():
        for start in range(0, len(method_cells), seeds_per_process):
            chunk = method_cells[start : start + seeds_per_process]
            stacks.append((CellStack(tuple(cell for cell, _ in chunk)), chunk[0][1]))
    return stacks


def method_name(recipe: Path) -> str:
    """A recipe's method: its file stem."""
    return recipe.stem


def plan_grid(
    recipes: Sequence[Path], seeds: Sequence[int], out: Path, found_seeds: bool = False, device: str | None = None,
) -> list[tuple[Cell, Recipe]]:
    """Every cell of the grid with its recipe, seed by seed (every method's first seed first, so
    a grid cut short holds whole seeds of the comparison). `found_seeds`: each method also with
    the seeds its folder already holds (OUT/<method>/seed-<S>), as its card lists them. `device`:
    where the cells' updates run (None: the recipes'). Every
    recipe is read first: RecipeError names a bad one, or two recipes with one method name,
    before anything runs."""
    methods: dict[str, Path] = {}
    for path in recipes:
        other = methods.setdefault(method_name(path), path)
        if other != path:
            raise RecipeError(f"{other} and {path} are both method '{method_name(path)}'; a grid's recipes need distinct file names")
    if len(set(seeds)) != len(seeds):
        raise RecipeError(f"the seeds {list(seeds)} repeat one")
    loaded = {method: load_recipe(path) for method, path in methods.items()}
    every = {method: set(seeds) | (seeds_in(out / method) if found_seeds else set()) for method in methods}
    return [
        (Cell(method, seed, path, out / method / f"seed-{seed}", device), loaded[method])
        for seed in sorted(set().union(*every.values())) for method, path in methods.items() if seed in every[method]
    ]


def seeds_in(folder: Path) -> set[int]:
    """The seeds of a method's grid folder: those of its seed-<S> folders and logs."""
    if not folder.is_dir():
        return set()
    names = (path.name.removesuffix(".log") for path in folder.iterdir())
    return {int(name[5:]) for name in names if name.startswith("seed-") and name[5:].isdigit()}


class CellRunner(Protocol):
    """Where cells run (LocalProcesses here, training.lab.grid_ray.RayCells on a Ray cluster)."""

    def start(self, cell: Cell | CellStack) -> Any:
        """Start the cell's (or stack's) run, its output appended to cell.log; returns a handle."""

    def poll(self, handle: Any) -> int | None:
        """The run's exit status once it has ended (STOPPED: stopped with a checkpoint), else None."""

    def stop(self, handle: Any) -> None:
        """Ask the run to stop: it writes a whole checkpoint and ends (asked twice: it ends at once)."""

    def close(self) -> None:
        """Release what the runner holds (the runs have ended)."""


class LocalProcesses:
    """Cells as processes of this machine, each in its own session (a terminal's Ctrl-C reaches
    the grid alone, which passes it on once), one torch and one BLAS thread each."""

    def __init__(self, program: Sequence[str] = RUN_PROGRAM) -> None:
        self.program = list(program)

    def start(self, cell: Cell | CellStack) -> subprocess.Popen:
        cell.log.parent.mkdir(parents=True, exist_ok=True)
        with open(cell.log, "ab") as log:
            return subprocess.Popen(
                [sys.executable, *self.program, *cell.arguments()], stdin=subprocess.DEVNULL, stdout=log,
                stderr=subprocess.STDOUT, start_new_session=True, env={**os.environ, "OMP_NUM_THREADS": "1"},
            )

    def poll(self, handle: subprocess.Popen) -> int | None:
        return handle.poll()

    def stop(self, handle: subprocess.Popen) -> None:
        if handle.poll() is None:
            handle.send_signal(signal.SIGTERM)

    def close(self) -> None:
        pass


@dataclass
class GridOutcome:
    """How the cells of a grid ended, by cell name."""

    finished: list[str]
    """cells finished before this run of the grid."""
    done: list[str]
    """cells that finished in this run."""
    failed: list[str]
    """cells whose run ended in an error (their log says which)."""
    stopped: list[str]
    """cells stopped by a signal with a whole checkpoint, or never started after one: they go on
    when the grid runs again."""
    elsewhere: list[str] = field(default_factory=list)
    """cells whose folder another run holds (training.run_lock): left to it."""

    @property
    def exit_status(self) -> int:
        """0: every cell finished; 130: stopped by a signal; 75: some cell runs in another
        process; 1: some cell failed."""
        return 1 if self.failed else STOPPED if self.stopped else RUN_HELD if self.elsewhere else 0


def last_line(path: Path, limit: int = 300) -> str:
    """The last non-empty line of a text file (at most `limit` characters; "" when none)."""
    try:
        with open(path, "rb") as handle:
            handle.seek(max(0, handle.seek(0, os.SEEK_END) - 4096))
            lines = [line.strip() for line in handle.read().decode(errors="replace").splitlines() if line.strip()]
    except OSError:
        return ""
    return lines[-1][:limit] if lines else ""


def run_grid(
    cells: Sequence[tuple[Cell | CellStack, Recipe]], runner: CellRunner, at_once: int, note: Callable[[str], None],
    stop_after_s: float | None = None,
) -> GridOutcome:
    """Run every cell (or stack of cells: `stack_cells`) not finished yet, at most `at_once`
    together, until each has ended.

    `note` gets a line for each cell that starts or ends, with the counts so far; a failed cell's
    line starts with "Error:" and names its log. SIGINT and SIGTERM (in the main thread) stop
    the grid: each is passed on to the running cells, and no cell starts after one. So does the
    end of `stop_after_s` seconds, once.
    """
    deadline = None if stop_after_s is None else time.monotonic() + stop_after_s
    outcome = GridOutcome([], [], [], [])
    waiting: list[Cell | CellStack] = []
    for cell, recipe in cells:
        if cell.finished(recipe):
            outcome.finished.append(cell.name)
        else:
            waiting.append(cell)
    if outcome.finished:
        note(f"{len(outcome.finished)} of {len(cells)} cells finished before this run: {', '.join(outcome.finished)}")
    running: dict[Cell | CellStack, Any] = {}
    signals: list[str] = []

    def counts() -> str:
        return (f"[{len(outcome.finished) + len(outcome.done)} done, {len(running)} running, "
                f"{len(outcome.failed)} failed, {len(waiting)} waiting]")

    asked: dict[Cell | CellStack, int] = {}  # signals passed on to each running cell

    def pass_on(cell: Cell | CellStack) -> None:
        while asked.get(cell, 0) < len(signals):
            runner.stop(running[cell])
            asked[cell] = asked.get(cell, 0) + 1

    def ask_to_stop(number: int, frame: object) -> None:
        signals.append(signal.Signals(number).name)
        for cell in list(running):
            pass_on(cell)

    handlers = {}
    if threading.current_thread() is threading.main_thread():
        handlers = {number: signal.signal(number, ask_to_stop) for number in (signal.SIGINT, signal.SIGTERM)}
    try:
        while waiting or running:
            while waiting and len(running) < at_once and not signals:
                cell = waiting.pop(0)
                running[cell] = runner.start(cell)
                pass_on(cell)  # a signal that came while it started
                note(f"{counts()} {cell.name}: started, log {cell.log}")
            if signals and not running:
                break
            time.sleep(POLL_S)
            if deadline is not None and time.monotonic() >= deadline and not signals:
                note(f"{counts()} the time limit is reached: stopping the running cells")
                ask_to_stop(signal.SIGTERM, None)
            for cell, handle in list(running.items()):
                status = runner.poll(handle)
                if status is None:
                    continue
                del running[cell]
                if status == 0:
                    outcome.done.append(cell.name)
                    note(f"{counts()} {cell.name}: finished")
                elif status == RUN_HELD:
                    outcome.elsewhere.append(cell.name)
                    note(f"{counts()} {cell.name}: another run holds its folder; left to it ({last_line(cell.log)})")
                elif status == STOPPED or signals:
                    outcome.stopped.append(cell.name)
                    note(f"{counts()} {cell.name}: stopped with a checkpoint; the grid run again goes on from it")
                else:
                    outcome.failed.append(cell.name)
                    note(f"Error: {cell.name} failed (exit {status}): {last_line(cell.log) or 'no output'}; "
                         f"log {cell.log}")
    finally:
        for number, handler in handlers.items():
            signal.signal(number, handler)
        runner.close()
    outcome.stopped.extend(cell.name for cell in waiting)
    return outcome
