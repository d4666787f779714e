"""A quick end-to-end training run for CI: train, checkpoint, resume, export, act.

The long training tests (tests/test_training_loop.py, tests/training/test_learner.py)
are marked slow; this one keeps the whole path exercised in the "not slow" suite in a
few seconds: a tiny network, a few hundred environment steps."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from terl_rt import Scenario, Simulator
from terl_rt.paper.seed_comparison import policy_identity
from terl_rt.policy.onnx_policy import OnnxPolicy
from training.__main__ import main
from training.checkpoint import load_network, read_counters
from training.config import Config
from training.seed_state import METRICS_FILE


def smoke_config(**changes) -> Config:
    return Config.of(
        model="terl", hidden=16, layers=1, heads=2, total_steps=320, num_envs=4, batch_size=32,
        buffer_size=5_000, learning_starts=80, target_network_frequency=160,
        eval_max_steps=10, snapshot_frequency=0, log_frequency=160, checkpoint_frequency=160,
    ).replace(**changes)


def test_train_resume_export_and_act_end_to_end(tmp_path):
    config_file = tmp_path / "smoke.json"
    smoke_config().to_file(config_file)
    out = tmp_path / "run"
    assert main(["train", "--config", str(config_file), "--out", str(out), "--quiet", "--threads", "1"]) == 0
    first = read_counters(out)
    assert first.env_step == 320 and first.updates > 0

    assert main(["train", "--resume", str(out), "--total-steps", "400", "--quiet", "--threads", "1"]) == 0
    second = read_counters(out)
    assert second.env_step == 400 and second.updates > first.updates
    kinds = [json.loads(line)["kind"] for line in (out / METRICS_FILE).read_text().splitlines()]
    assert "resume" in kinds and kinds[-1] == "train"

    onnx_path = tmp_path / "smoke.onnx"
    assert main(["export", str(out), "-o", str(onnx_path)]) == 0
    policy = OnnxPolicy(onnx_path)
    assert policy.metadata["terl.training_steps"] == "400"
    # exported without --seed, its run's seed still tells it apart from the method's other seeds in a report
    assert policy_identity(policy.metadata) == ("TERL", smoke_config().run.seed)
    simulator = Simulator(Scenario.preset("small-11"), seed=0)
    actions = policy.act(simulator.reset())
    assert actions.shape == (11,) and np.all((actions >= 0) & (actions < 9))
    simulator.step(actions)


def test_model_card_reads_the_run_it_describes(tmp_path):
    out = tmp_path / "run"
    config = smoke_config(model="iqn", layers=0, heads=0, snapshot_frequency=160, snapshot_episodes=1)
    config_file = tmp_path / "iqn.json"
    config.to_file(config_file)
    assert main(["train", "--config", str(config_file), "--out", str(out), "--quiet", "--threads", "1"]) == 0
    card_path = tmp_path / "iqn.md"
    assert main(["card", str(out), "--onnx", "exported/comparison/iqn-seed-1.onnx", "--recipe", "recipes/comparison/iqn.toml",
                 "-o", str(card_path)]) == 0
    card = card_path.read_text()
    counters = read_counters(out)
    model = load_network(out)[0]
    assert card.startswith("# exported/comparison/iqn-seed-1.onnx — IQN, a run of 0 k environment steps")
    assert f"**{sum(p.numel() for p in model.parameters()):,} parameters**" in card
    assert f"**320 environment steps, {counters.updates:,} gradient updates" in card
    snapshots = [json.loads(line) for line in (out / METRICS_FILE).read_text().splitlines()]
    snapshots = [r for r in snapshots if r["kind"] == "snapshot"]
    assert len(snapshots) == 2
    assert sum(line.startswith("| 0 k |") for line in card.splitlines()) == 2
    assert f"at {counters.best_step:,} steps" in card
    digest = hashlib.sha256(Path("exported/comparison/iqn-seed-1.onnx").read_bytes()).hexdigest()
    assert f"- **Weights**: `exported/comparison/iqn-seed-1.onnx`, sha256 `{digest}`." in card
    assert "- **Recipe**: [`recipes/comparison/iqn.toml`]" in card
