"""A fine-tune's start: a checkpoint, a snapshot or an exported policy, laid down as the whole
checkpoint that the first segment of a recipe with `from_step` continues (training.lab.recipe).

    python -m training run recipes/scale-fine-tune.toml --start runs/a/1-curriculum --out runs/b
    python -m training run recipes/scale-fine-tune.toml --start exported/comparison/terl-authors-seed-1.onnx --out runs/c

What a start is:
- a checkpoint folder (state.json with RNG states): copied whole (weights, target, Adam
  moments, counters; not its replay buffer, which the first segment refills), with its
  generators where it ran with the run's seed (a recipe continued from its own first segment
  goes on as one run would) and generators seeded by the run's seed where it did not (several
  seeds from one start are several runs, not one run repeated);
- a snapshot folder (training.checkpoint.save_snapshot: the online network and its counters), or
  a checkpoint folder that kept its online network alone (a committed best/);
- an exported policy (`.onnx`): its weights read back from the graph (training.onnx_weights),
  its environment step from `terl.training_steps`, its config from `terl.training_config`.
A snapshot or a policy holds no target network, optimizer or generators: the target starts as
a copy of the online network, Adam starts with no moments, and the generators are seeded by
the run's seed. Its best snapshot score is not carried (it was measured by another run).

A recipe may bring a start's values to the scale of its own rewards (`start_reward_scale`,
training.lab.recipe) instead of carrying the start's: the value head's last layer, online and
target, is multiplied by the new scale over the start's (every quantile is linear in it, so the
values are the same values in the new units), Adam's moments are dropped (they were of the old
units' gradients), and the start's config takes the new scale.

The start is written to OUT/0-start/ (OUT/seed-<S>/0-start/ for seeds trained together) with
start.json beside it (what it came from, its kind and its weights' sha256), so the run names
its start, the model card reads it, and a rerun of the same command finds it in place.
"""

from __future__ import annotations

import hashlib
import json
import random
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from terl_rt.files import atomic_output
from terl_rt.policy.contract import (
    META_HEADS, META_HIDDEN, META_LAYERS, META_MODEL, META_TRAINED_ON, META_TRAINING_STEPS,
)
from training.adam import one_seed_state_dict
from training.checkpoint import (
    CONFIG_FILE, META_TRAINING_CONFIG, MODEL_FILE, OPTIMIZER_FILE, STATE_FILE, TARGET_FILE, Counters,
    TrainingState, load_checkpoint, load_network, read_config, read_counters, save_checkpoint,
)
from training.config import Config
from training.networks import network_from_config

START_FOLDER = "0-start"
"""The folder of a run (or of a seed of it) that holds its start."""
START_RECORD = "start.json"
"""What the start came from: {"source", "kind", "sha256", "env_step", "generators"} ("the start's",
or "seeded by S": the run's seed S), and "values_rescaled" (the factor) where its values were brought
to another reward scale."""
VALUE_LAYER = ("head.out.weight", "head.out.bias")
"""The value head's last layer: every quantile (and Q-value) is linear in it."""
CHECKPOINT_FILES = (MODEL_FILE, TARGET_FILE, OPTIMIZER_FILE, CONFIG_FILE, STATE_FILE)
"""A whole checkpoint's files, state.json last (it marks the checkpoint complete)."""
KINDS = ("checkpoint", "snapshot", "policy")


class StartError(ValueError):
    """A start that cannot be read; the message names the path and what is wrong."""


def seed_start(start: str, seed: int) -> Path:
    """The start of `seed`: `start` with every "{seed}" replaced by the seed's number."""
    return Path(start.replace("{seed}", str(seed)))


def start_kind(source: Path) -> str:
    """"checkpoint", "snapshot" or "policy": what `source` is (StartError when none)."""
    if source.suffix == ".onnx":
        if not source.is_file():
            raise StartError(f"{source}: no such policy file")
        return "policy"
    state_path = source / STATE_FILE
    if not state_path.is_file():
        raise StartError(f"{source}: not a checkpoint, snapshot or .onnx policy (no {STATE_FILE} in it)")
    try:
        state = json.loads(state_path.read_text())
    except (OSError, json.JSONDecodeError) as error:
        raise StartError(f"{state_path}: unreadable ({error})") from None
    # a checkpoint resumes: its generators and every file of it (a kept best/ may hold its model alone)
    whole = "rng" in state and all((source / name).is_file() for name in CHECKPOINT_FILES)
    return "checkpoint" if whole else "snapshot"


def fresh_rng_states(seed: int) -> dict:
    """The generator states of a run that starts at `seed` (training.checkpoint.rng_states' layout)."""
    version, internal, gauss = random.Random(seed).getstate()
    return {
        "python": [version, list(internal), gauss],
        "numpy": np.random.default_rng(seed).bit_generator.state,
        "torch": torch.Generator().manual_seed(seed).get_state().tolist(),
    }


def _policy_weights(source: Path) -> tuple[torch.nn.Module, Config, Counters]:
    """The network, config and counters an exported policy records."""
    from training.onnx_weights import WeightsNotFound, network_from_onnx

    try:
        model, metadata = network_from_onnx(source)
    except WeightsNotFound as error:
        raise StartError(str(error)) from None
    try:
        config = Config.from_dict(json.loads(metadata[META_TRAINING_CONFIG]), source=str(source))
    except KeyError:
        config = Config()
    config = config.replace(model=metadata[META_MODEL], hidden=int(metadata[META_HIDDEN]),
                            layers=int(metadata[META_LAYERS]), heads=int(metadata[META_HEADS]))
    trained_on = metadata.get(META_TRAINED_ON, "")
    stages = [] if trained_on in ("", "untrained") else trained_on.replace("..", ",").split(",")
    counters = Counters(env_step=int(metadata.get(META_TRAINING_STEPS, "0")), stages=stages)
    return model, config, counters


def rescale_values(folder: Path, reward_scale: float) -> float:
    """Bring the values of the whole checkpoint in `folder` to rewards taught x `reward_scale`
    (VALUE_LAYER of the online and target networks times `reward_scale` over the checkpoint's own
    scale, Adam's moments dropped, the config's scale replaced); returns the factor (1.0: it was
    at that scale, nothing is written)."""
    config = read_config(folder)
    factor = reward_scale / config.data.reward_scale
    if factor == 1.0:
        return factor
    state = load_checkpoint(folder)
    for weights in (state.online, state.target):
        for name in VALUE_LAYER:
            weights[name] = weights[name] * factor
    optimizer = one_seed_state_dict(len(list(network_from_config(config.network).parameters())), config.learner.learning_rate)
    save_checkpoint(folder, config.replace(reward_scale=reward_scale), replace(state, optimizer=optimizer))
    return factor


def place_start(source: Path, folder: Path, seed: int, reward_scale: float | None = None) -> Counters:
    """Write the start `source` as a whole checkpoint into `folder` (START_FOLDER of a run) and
    return its counters; a folder that already holds this start is left as it is. With
    `reward_scale`, the start's values are brought to that scale (`rescale_values`)."""
    kind = start_kind(source)
    weights = source if kind == "policy" else source / MODEL_FILE
    digest = hashlib.sha256(weights.read_bytes()).hexdigest()
    record_path = folder / START_RECORD
    if record_path.is_file() and (folder / STATE_FILE).is_file():
        record = json.loads(record_path.read_text())
        if record.get("sha256") != digest:
            raise StartError(f"{folder} holds another start ({record.get('source')}, sha256 {record.get('sha256')}), "
                             f"not {source}: use another --out, or remove {folder}")
        placed_scale = read_config(folder).data.reward_scale
        if reward_scale is not None and placed_scale != reward_scale:
            raise StartError(f"{folder} holds this start with its values at reward scale {placed_scale}, "
                             f"not {reward_scale}: use another --out, or remove {folder}")
        return read_counters(folder)
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    generators = f"seeded by {seed}"
    if kind == "checkpoint":
        for name in CHECKPOINT_FILES:
            shutil.copyfile(source / name, folder / name)
        counters = read_counters(folder)
        if read_config(folder).run.seed == seed:
            generators = "the start's"
        else:
            state = json.loads((folder / STATE_FILE).read_text())
            state["rng"] = fresh_rng_states(seed)
            with atomic_output(folder / STATE_FILE, replace=True) as temporary:
                temporary.write_text(json.dumps(state))
    else:
        if kind == "policy":
            model, config, counters = _policy_weights(source)
        else:
            model, config, counters = load_network(source)
        counters = replace(counters, best_score=None, best_step=None, replay_transitions=0)
        weights_now = model.state_dict()
        optimizer = one_seed_state_dict(len(list(model.parameters())), config.learner.learning_rate)
        save_checkpoint(folder, config, TrainingState(weights_now, weights_now, optimizer, counters,
                                                      fresh_rng_states(seed)))
    record = {"source": str(source), "kind": kind, "sha256": digest, "env_step": counters.env_step,
              "generators": generators}
    if reward_scale is not None and (factor := rescale_values(folder, reward_scale)) != 1.0:
        record["values_rescaled"] = factor
    with atomic_output(record_path, replace=True) as temporary:
        temporary.write_text(json.dumps(record, indent=2) + "\n")
    return counters


def read_start(run_folder: Path) -> dict | None:
    """The start.json of a run folder's start, None for a run that started from nothing."""
    path = Path(run_folder) / START_FOLDER / START_RECORD
    return json.loads(path.read_text()) if path.is_file() else None
