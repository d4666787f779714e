"""Checkpoints of a training run, and the ONNX export of one.

A checkpoint is a folder (the run's output folder) holding the last save:
- model.safetensors, target.safetensors: online and target network weights;
- optimizer.pt: the Adam state dict (torch.save, read back with weights_only=True);
- config.json: the `Config` of the run (by part; earlier runs wrote it flat, which still reads);
- state.json: counters and the Python, NumPy and torch RNG states, written last,
  so a folder with a state.json holds a complete checkpoint.
A snapshot (`save_snapshot`, RunConfig.keep_snapshots) holds the online network, config.json
and a state.json of counters alone: it exports and evaluates, it does not resume.
Nothing here unpickles arbitrary objects.
"""

from __future__ import annotations

import json
import random
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import load_file, save_file

from terl_rt.files import atomic_output
from terl_rt.policy.contract import META_TRAINED_ON, META_TRAINING_STEPS
from training.config import Config
from training.export import export_onnx
from training.networks import QNetwork, network_from_config

FORMAT_VERSION = 1
"""Version of the checkpoint layout, stored in state.json."""
MODEL_FILE = "model.safetensors"
TARGET_FILE = "target.safetensors"
OPTIMIZER_FILE = "optimizer.pt"
CONFIG_FILE = "config.json"
STATE_FILE = "state.json"
META_TRAINING_CONFIG = "terl.training_config"
"""Metadata key of an exported policy: the training Config as JSON (training's own, not the contract's)."""


@dataclass
class Counters:
    """How far a run has come; saved in state.json and continued on resume."""

    env_step: int = 0
    """environment steps taken (num_envs per batch step)."""
    updates: int = 0
    """gradient updates done."""
    episodes: int = 0
    """training episodes finished."""
    wall_seconds: float = 0.0
    """seconds spent training, summed over resumes."""
    stages: list[str] = field(default_factory=list)
    """scenarios trained on, in the order first met (e.g. curriculum-1, curriculum-2)."""
    best_score: float | None = None
    """score of the best snapshot so far (training.seed_state.snapshot_score), None before the first."""
    best_step: int | None = None
    """environment step of that snapshot."""
    replay_transitions: int | None = None
    """transitions the replay buffer held at this checkpoint: what a resume without the saved
    buffer refills before updating again (None in checkpoints from before it was recorded)."""
    snapshot_evaluator: str | None = None
    """what measured the snapshots behind best_score (training.seed_state.SNAPSHOT_EVALUATOR; None in
    checkpoints from before snapshots ran through terl_rt.evaluation)."""


def rng_states(rng: np.random.Generator, torch_generator: torch.Generator) -> dict[str, Any]:
    """JSON-serialisable RNG states: Python `random`, a seed's NumPy generator and its torch CPU
    generator (its quantile fractions: training.learner.Learner.generators)."""
    version, internal, gauss = random.getstate()
    return {
        "python": [version, list(internal), gauss],
        "numpy": rng.bit_generator.state,
        "torch": torch_generator.get_state().tolist(),
    }


def restore_rng_states(states: dict[str, Any], rng: np.random.Generator, torch_generator: torch.Generator) -> None:
    """Inverse of `rng_states`: set Python's generator, `rng` and `torch_generator`."""
    version, internal, gauss = states["python"]
    random.setstate((version, tuple(internal), gauss))
    rng.bit_generator.state = states["numpy"]
    torch_generator.set_state(torch.tensor(states["torch"], dtype=torch.uint8))


@dataclass
class TrainingState:
    """What a checkpoint holds besides its config: one seed's learner and generators, as state dicts."""

    online: dict[str, torch.Tensor]
    """the online network's state dict."""
    target: dict[str, torch.Tensor]
    """the target network's state dict."""
    optimizer: dict[str, Any]
    """a plain torch.optim.Adam's state dict over the online network's parameters."""
    counters: Counters
    rng: dict[str, Any]
    """`rng_states`."""


def _replace_file(path: Path, write) -> None:
    """`write(temporary)`, then rename it over `path`: a crash leaves the old file whole."""
    with atomic_output(path, replace=True) as temporary:
        write(temporary)


def save_checkpoint(folder: str | Path, config: Config, state: TrainingState) -> Path:
    """Write the checkpoint files into `folder` (created if needed) and return it."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    _write_weights(folder / MODEL_FILE, state.online, config, state.counters)
    _write_weights(folder / TARGET_FILE, state.target, config, state.counters)
    _replace_file(folder / OPTIMIZER_FILE, lambda path: torch.save(state.optimizer, path))
    _replace_file(folder / CONFIG_FILE, config.to_file)
    _write_state(folder, {"format": FORMAT_VERSION, "counters": asdict(state.counters), "rng": state.rng})
    return folder


def save_snapshot(folder: str | Path, config: Config, model: QNetwork, counters: Counters) -> Path:
    """Write the online network alone into `folder` (model.safetensors, config.json and a
    state.json of counters): enough to export or evaluate it, not to resume training."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    _write_weights(folder / MODEL_FILE, model.state_dict(), config, counters)
    _replace_file(folder / CONFIG_FILE, config.to_file)
    _write_state(folder, {"format": FORMAT_VERSION, "counters": asdict(counters)})
    return folder


def _write_weights(path: Path, weights: dict[str, torch.Tensor], config: Config, counters: Counters) -> None:
    """`weights` as safetensors, its metadata one key (`terl`: the config and environment step as
    JSON, keys sorted): safetensors writes metadata keys in a hash map's order, which changes from
    process to process, so one key is what makes the same weights the same bytes."""
    metadata = {"terl": json.dumps({"config": config.to_dict(), "env_step": counters.env_step}, sort_keys=True)}
    state = {key: value.detach().cpu().contiguous() for key, value in weights.items()}
    _replace_file(path, lambda temporary: save_file(state, str(temporary), metadata=metadata))


def _write_state(folder: Path, state: dict[str, Any]) -> None:
    """state.json, written last: a folder with one holds a whole checkpoint or snapshot."""
    _replace_file(folder / STATE_FILE, lambda path: path.write_text(json.dumps(state) + "\n"))


def _checkpoint_folder(source: str | Path) -> Path:
    """The folder of a checkpoint given as the folder or one of its files."""
    source = Path(source)
    folder = source.parent if source.is_file() else source
    if not (folder / STATE_FILE).is_file():
        raise FileNotFoundError(f"{source}: no checkpoint here (expected {folder / STATE_FILE})")
    return folder


def read_config(source: str | Path) -> Config:
    """The config saved with a checkpoint (folder or one of its files)."""
    return Config.from_file(_checkpoint_folder(source) / CONFIG_FILE)


def read_counters(source: str | Path) -> Counters:
    """The counters saved with a checkpoint."""
    return Counters(**_read_state(_checkpoint_folder(source))["counters"])


def _read_state(folder: Path) -> dict[str, Any]:
    state = json.loads((folder / STATE_FILE).read_text())
    if state.get("format") != FORMAT_VERSION:
        raise ValueError(
            f"{folder / STATE_FILE}: checkpoint format {state.get('format')}, expected {FORMAT_VERSION}"
        )
    return state


def load_checkpoint(source: str | Path) -> TrainingState:
    """The learner state, counters and RNG states saved by `save_checkpoint`."""
    folder = _checkpoint_folder(source)
    state = _read_state(folder)
    if "rng" not in state:
        raise ValueError(
            f"{folder}: a snapshot of the online network alone (no target network, optimizer or RNG "
            "states), which can be exported or evaluated but not resumed; resume from its run folder or best/"
        )
    return TrainingState(
        online=load_file(str(folder / MODEL_FILE)),
        target=load_file(str(folder / TARGET_FILE)),
        optimizer=torch.load(folder / OPTIMIZER_FILE, weights_only=True),
        counters=Counters(**state["counters"]),
        rng=state["rng"],
    )


def load_network(source: str | Path) -> tuple[QNetwork, Config, Counters]:
    """The online network of a checkpoint (eval mode), its config and counters."""
    folder = _checkpoint_folder(source)
    config = read_config(folder)
    model = network_from_config(config.network)
    model.load_state_dict(load_file(str(folder / MODEL_FILE)))
    return model.eval(), config, read_counters(folder)


def trained_on(stages: list[str]) -> str:
    """The `terl.trained_on` text: "curriculum-1..curriculum-5" for a walked curriculum
    (first and last stage met), else the scenario names joined by commas."""
    if not stages:
        return "untrained"
    if len(stages) > 1 and all(name.startswith("curriculum-") for name in stages):
        return f"{stages[0]}..{stages[-1]}"
    return ",".join(stages)


def export_checkpoint(source: str | Path, output: str | Path, metadata: dict[str, str] | None = None) -> Path:
    """Export a checkpoint's online network as a contract-v1 ONNX policy at `output`.

    Adds `terl.training_steps` (environment steps), `terl.trained_on`, the training config and
    the caller's `metadata` (str -> str, e.g. a grid's `terl.method` and `terl.seed`) to the
    metadata; `export_onnx` checks parity with torch before returning.
    """
    model, config, counters = load_network(source)
    props = {
        META_TRAINING_STEPS: str(counters.env_step),
        META_TRAINED_ON: trained_on(counters.stages),
        META_TRAINING_CONFIG: json.dumps(config.to_dict(), sort_keys=True),
        **(metadata or {}),
    }
    return export_onnx(model, output, props)
