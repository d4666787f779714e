"""Model cards of trained runs: `python -m training card RUN_DIR --onnx FILE -o CARD.md`.

A card says what a shipped policy is (body, size), how it was trained (config, steps,
updates, episodes, wall clock, machine), which snapshot was shipped and why (every
snapshot evaluation of the run), read from the run's checkpoint and metrics.jsonl, so
the cards of runs trained the same way read the same way.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING

from terl_rt.policy.models import model_title
from training.config import Config
from training.lab.curves import read_metrics

if TYPE_CHECKING:
    import torch

DEFAULT_MACHINE = "one core of the 2-core CPU machine (one torch thread)"
"""Where a run trained, in words, unless a card is told otherwise."""


class CardError(ValueError):
    """A comparison file the card cannot use; the message names it."""


def snapshot_table(snapshots: list[dict], preset: str) -> list[str]:
    """Markdown lines of a table of a run's snapshot records, one row each, in order."""
    return [
        "| step | score | current stage | " + preset + " |",
        "|---:|---:|---|---|",
        *(snapshot_row(record) for record in snapshots),
    ]


def snapshot_row(record: dict) -> str:
    """A snapshot record as a table row: step, score, then each evaluation's success / travel
    time / collision ratio."""
    cells = [
        f"{e['success_rate']:.2f} / {e['travel_time_s_mean']:.1f} s / {e['collision_ratio_mean']:.3f}"
        for e in record["evaluations"]
    ]
    cells[0] = f"{record['evaluations'][0]['scenario']}: {cells[0]}"  # the stage changes along the run
    chosen = " (best so far)" if record.get("best") else ""
    return f"| {record['env_step'] // 1000} k | {record['score']:.3f}{chosen} | " + " | ".join(cells) + " |"


def never_encircled(snapshots: list[dict]) -> list[str]:
    """A line saying so when no snapshot evaluation of the run succeeded once (else none)."""
    if any(e["success_rate"] > 0 for r in snapshots for e in r["evaluations"]):
        return []
    return ["- **No snapshot of this run encircled** (success 0 in every evaluation below): the rule "
            "picked the least bad score, which says little about the network."]


def evaluation_lines(comparison: str | Path, model: str) -> list[str]:
    """The per-group table of `model` in a comparison.json written by `terl-rt report`
    (several policies), with its 95 % intervals; CardError when it is not one or lacks the model."""
    try:
        data = json.loads(Path(comparison).read_text())
        runs = [run for run in data["methods"] if run["policy"]["metadata"].get("terl.model") == model]
    except (json.JSONDecodeError, KeyError, TypeError, AttributeError) as error:
        raise CardError(f"{comparison}: not a comparison.json of terl-rt report ({error!r})") from None
    if not runs:
        raise CardError(f"{comparison}: no policy of model '{model}' in this comparison")
    run = runs[0]
    lines = [
        f"`{data['command']}` ({data['date'][:16].replace('T', ' ')} UTC); full tables and the paper's numbers in `docs/comparison.md`.",
        "Group means with 95 % intervals (bootstrap over the episodes within each preset):",
        "",
        "| group | presets | success | travel time (s) | collision ratio |",
        "|---|---|---:|---:|---:|",
    ]
    for group in run["groups"]:
        interval = group["ci95"]
        lines.append(
            f"| {group['group']} | {', '.join(group['presets'])} "
            f"| {group['success_rate']:.2f} [{interval['success_rate'][0]:.2f}, {interval['success_rate'][1]:.2f}] "
            f"| {group['travel_time_s_mean']:.1f} [{interval['travel_time_s'][0]:.1f}, {interval['travel_time_s'][1]:.1f}] "
            f"| {group['collision_ratio_mean']:.3f} [{interval['collision_ratio'][0]:.3f}, "
            f"{interval['collision_ratio'][1]:.3f}] |"
        )
    return lines


def provenance_lines(onnx: str | Path, recipe: str | Path) -> list[str]:
    """The card's lines that tie a shipped file to what made it: its recipe and the sha256 of its
    weights (the ONNX file's bytes, as `terl-rt info` and OnnxPolicy.sha256 report them)."""
    command = f"python -m training run {recipe} --out runs/{Path(onnx).stem}"
    return [recipe_line(recipe, Path(onnx).parent, command), weights_line(onnx)]


def recipe_line(recipe: str | Path, card_folder: Path, command: str) -> str:
    """The card's line naming the recipe (linked from the card's folder) and the command that runs it."""
    return f"- **Recipe**: [`{recipe}`]({os.path.relpath(recipe, card_folder)}) (`{command}`)."


def weights_line(onnx: str | Path) -> str:
    """The card's line naming a shipped file and the sha256 of its bytes."""
    return f"- **Weights**: `{onnx}`, sha256 `{hashlib.sha256(Path(onnx).read_bytes()).hexdigest()}`."


def model_lines(model: torch.nn.Module, config: Config) -> list[str]:
    """The card's lines on the network: its body (the first clause of its class docstring) and size."""
    network = config.network
    parameters = sum(p.numel() for p in model.parameters())
    body = " ".join(type(model).__doc__.split("\n\n")[0].split(";")[0].split()).rstrip(".") + "."
    size = f"H = {network.hidden}" + (f", L = {network.layers}, h = {network.heads}" if network.layers else "")
    return [f"- {body}", f"- {size}: **{parameters:,} parameters**."]


def settings(config: Config) -> str:
    """The learner's settings a card names, in words: reward, learning rate, dropout, batch, worlds."""
    return (f"Reward `{config.data.reward}`, learning rate {config.learner.learning_rate:g}, dropout "
            f"{config.network.dropout:g}, batch {config.learner.batch_size}, {config.schedule.num_envs} worlds")


def model_card(
    run: str | Path, onnx: str | Path, recipe: str | Path, machine: str, comparison: str | Path | None = None,
) -> str:
    """The markdown card of the policy `onnx` exported from run folder `run`'s best snapshot.

    Args:
        run: the run folder (checkpoint, metrics.jsonl, best/): the recipe's last segment.
        onnx: the shipped ONNX file, as the repository names it (read for its sha256).
        recipe: the recipe that made it, as the repository names it.
        machine: where it trained, in words.
        comparison: a comparison.json of `terl-rt report` holding this model (its evaluation
            section); None: the card points to docs/comparison.md.
    """
    from training.checkpoint import load_network  # here, not above: `python -m training --help` does not import torch

    run = Path(run)
    best = run / "best"
    model, config, best_counters = load_network(best if best.is_dir() else run)
    _, _, counters = load_network(run)
    network = config.network
    snapshots = [r for r in read_metrics(run / "metrics.jsonl") if r.get("kind") == "snapshot"]
    name = model_title(network.model)
    lines = [
        f"# {onnx} — {name}, a run of {counters.env_step // 1000} k environment steps",
        "",
        f"The `{network.model}` network of the paper's comparison (policy.md sections 1 and 4), trained with",
        "the shipped settings, budget, curriculum, seed and snapshot rule; only the network differs.",
        "",
        *provenance_lines(onnx, recipe),
        "",
        "## Model",
        *model_lines(model, config),
        "",
        "## Training",
        f"- {settings(config)}, seed {config.run.seed}.",
        f"- **{counters.env_step:,} environment steps, {counters.updates:,} gradient updates, "
        f"{counters.episodes:,} episodes, {counters.wall_seconds:,.0f} s** ({counters.wall_seconds / 3600:.1f} h) "
        f"on {machine}.",
        f"- Shipped: the best snapshot, at {best_counters.env_step:,} steps "
        f"(score {counters.best_score:.3f}: mean over its evaluations of success - collision ratio - "
        "time / limit).",
        *never_encircled(snapshots),
        "",
        "## Snapshot evaluations",
        "",
        "Greedy, episode k with seed + k (terl_rt.evaluation), every snapshot of the run: success / travel time /",
        f"collision ratio of {config.run.snapshot_episodes} episodes of the current curriculum stage and of "
        f"{config.run.snapshot_preset}.",
        "",
        *snapshot_table(snapshots, config.run.snapshot_preset),
        "",
        "## Evaluation on the paper's presets",
        "",
        *(evaluation_lines(comparison, network.model) if comparison is not None else
          ["Beside TERL and the other baselines in `docs/comparison.md` (`terl-rt report --policy exported`)."]),
        "",
    ]
    return "\n".join(lines)
