"""Shipping a grid (training.lab.grid): every finished seed's policy and one card per method.

Into a folder (exported/comparison): `<method>-seed-<S>.onnx`, the cell's shipped checkpoint
(its recipe's `ships_from`: the run's best snapshot, or its last checkpoint) with `terl.method`
and `terl.seed` in its metadata; `<method>.md`, the method's card, every seed a row of its
table, a seed that failed or has not finished included; `<method>-seeds.png`, every seed's
curves in one figure.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from terl_rt.files import atomic_output
from terl_rt.policy.contract import META_METHOD, META_SEED
from terl_rt.policy.models import model_title
from training.checkpoint import Counters, export_checkpoint, read_config, read_counters
from training.lab.card import model_lines, recipe_line, settings, snapshot_row, weights_line
from training.lab.curves import plot_seed_curves, read_metrics
from training.lab.grid import Cell
from training.lab.recipe import Recipe, continuing, recipe_finished, segment_folder, shipped_checkpoint
from training.lab.start import START_FOLDER, read_start
from training.networks import network_from_config
from training.seed_state import METRICS_FILE


def seed_file(folder: Path, cell: Cell) -> Path:
    """Where a cell's policy ships: FOLDER/<method>-seed-<S>.onnx."""
    return folder / f"{cell.method}-seed-{cell.seed}.onnx"


def cell_metrics(recipe: Recipe, cell: Cell) -> list[dict[str, Any]]:
    """A cell's metrics records, every segment's metrics.jsonl in order (none where none is written)."""
    records: list[dict[str, Any]] = []
    for index, segment in enumerate(recipe.segments, start=1):
        path = segment_folder(cell.out, index, segment) / METRICS_FILE
        if path.is_file():
            records.extend(read_metrics(path))
    return records


def ship_grid(cells: Sequence[tuple[Cell, Recipe]], folder: Path, machine: str) -> list[Path]:
    """Export every finished cell's policy into `folder` and write each method's card and figure
    (its cells in order, a card's rows); returns the files written. `machine`: where the cells
    trained, in words."""
    folder.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    methods: dict[str, list[tuple[Cell, Recipe]]] = {}
    for cell, recipe in cells:
        methods.setdefault(cell.method, []).append((cell, recipe))
    for method, seeds in methods.items():
        shipped = {
            cell: export_checkpoint(shipped_checkpoint(recipe, cell.out), seed_file(folder, cell),
                                    {META_METHOD: method, META_SEED: str(cell.seed)})
            for cell, recipe in seeds if recipe_finished(recipe, cell.out)
        }
        metrics = {cell: cell_metrics(recipe, cell) for cell, recipe in seeds}
        figure = plot_seed_curves({f"seed {cell.seed}": records for cell, records in metrics.items()},
                                  folder / f"{method}-seeds.png", title=f"{method}: every seed",
                                  star_best=seeds[0][1].ships_from == "best")
        card = folder / f"{method}.md"
        with atomic_output(card, replace=True) as partial:
            partial.write_text(method_card(method, seeds, shipped, metrics, figure, machine))
        written += [*shipped.values(), figure, card]
    return written


def method_card(
    method: str, seeds: Sequence[tuple[Cell, Recipe]], shipped: dict[Cell, Path],
    metrics: dict[Cell, list[dict[str, Any]]], figure: Path, machine: str,
) -> str:
    """The markdown card of one method of a grid: its recipe, every seed's weights, the network,
    the settings, the recipe's notes (`Recipe.notes`: where it follows the paper or differs), and
    a row per seed (a seed not shipped says so and names its log)."""
    recipe = continuing(seeds[0][1], seeds[0][0].out)
    config = recipe.segments[-1].config
    name = model_title(config.network.model)
    card_folder = figure.parent
    command = (f"python -m training grid {recipe.path} --seeds {','.join(str(cell.seed) for cell, _ in seeds)} "
               f"--out {seeds[0][0].out.parent.parent} --ship {card_folder}")
    lines = [
        f"# {card_folder / method} — {name}, {len(seeds)} seeds of {config.schedule.total_steps:,} environment steps",
        "",
        f"The `{config.network.model}` network of the paper's comparison (policy.md sections 1 and 4), trained by "
        f"`{recipe.path}` once a seed, each seed a run of its own. Every seed stays in the table, one that never "
        "learned or did not finish included: together they say how reliably the method learns.",
        "",
        recipe_line(recipe.path, card_folder, command),
        *(weights_line(shipped[cell]) for cell, _ in seeds if cell in shipped),
        "",
        "## Model",
        *model_lines(network_from_config(config.network), config),
        "",
        "## Training",
        f"- {settings(config)}; on {machine}.",
        "- Segments: " + ", ".join(f"{s.name} to {s.config.schedule.total_steps:,} steps" for s in recipe.segments)
        + ".",
        *start_lines(seeds),
        shipped_line(recipe),
        "",
        *(["## The recipe's notes", "", "```text", *recipe.notes, "```", ""] if recipe.notes else []),
        "## Seeds",
        "",
        f"![every seed's curves]({figure.name})",
        "",
        f"| seed | environment steps | updates | wall clock | shipped snapshot | score | current stage | "
        f"{config.run.snapshot_preset} |",
        "|---:|---:|---:|---:|---:|---:|---|---|",
        *(seed_row(cell, recipe, cell in shipped, metrics[cell]) for cell, recipe in seeds),
        "",
    ]
    return "\n".join(lines)


def start_lines(seeds: Sequence[tuple[Cell, Recipe]]) -> list[str]:
    """The card's line on what the seeds continue, for a recipe that continues a start: each
    seed's start (training.lab.start: its source, what it is, its network and step count)."""
    starts = {cell.seed: (read_start(cell.out), cell.out / START_FOLDER) for cell, _ in seeds}
    if not any(record for record, _ in starts.values()):
        return []
    described = []
    for seed, (record, folder) in starts.items():
        if record is None:
            described.append(f"seed {seed}: not laid down yet")
            continue
        network = read_config(folder).network
        size = f"H = {network.hidden}" + (f", L = {network.layers}" if network.layers else "")
        described.append(f"seed {seed}: `{record['source']}` (a {record['kind']}, `{network.model}` {size}, "
                         f"{record['env_step']:,} steps)")
    return ["- Start: each seed continues its own, its network and step count carried (the segments' steps "
            "move with it): " + "; ".join(described) + "."]


def shipped_line(recipe: Recipe) -> str:
    """The card's line on what each seed ships: its best snapshot by the snapshot score, or with
    `ships_from = "last"` its last checkpoint, the snapshots then a learning curve only."""
    config = recipe.segments[-1].config
    evaluations = (f"{config.run.snapshot_episodes} episodes of the current stage and of {config.run.snapshot_preset} "
                   f"from seed {config.run.eval_seed}, seeds no report uses")
    if recipe.ships_from == "last":
        return (f"- Shipped: each seed's last checkpoint ({config.schedule.total_steps:,} steps); its snapshots "
                f"({evaluations}) choose nothing.")
    return (f"- Shipped: each seed's best snapshot (score: mean over its evaluations of success - collision ratio - "
            f"time / limit; {evaluations}).")


def seed_row(cell: Cell, recipe: Recipe, is_shipped: bool, records: list[dict[str, Any]]) -> str:
    """One seed's row of a method card: its run's counters and its shipped snapshot's evaluation,
    or why it has none."""
    if not is_shipped:
        logs = ", ".join(f"`{path}`" for path in cell.logs())
        why = f"see {logs}" if logs else "no log (never run)"
        return f"| {cell.seed} | not finished (failed, stopped or not run): {why} | | | | | | |"
    counters: Counters = read_counters(shipped_checkpoint(recipe, cell.out))
    last = read_counters(segment_folder(cell.out, len(recipe.segments), recipe.segments[-1]))
    head = f"| {cell.seed} | {last.env_step:,} | {last.updates:,} | {last.wall_seconds / 3600:.1f} h "
    chosen = [r for r in records if r.get("kind") == "snapshot" and r["env_step"] == counters.env_step]
    if not chosen:  # shipped from the last checkpoint (ships_from = "last"), no snapshot there
        return head + f"| {counters.env_step // 1000} k (last) | | | |"
    return head + snapshot_row(chosen[-1])
