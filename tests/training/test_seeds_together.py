"""Seeds trained together (training.networks.stacked, training.learner): each seed of a stack is
exactly itself, and a run of several seeds lays each out as a one-seed run does."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch

from terl_rt.sim.rollout import Rollout
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.world import World
from training.__main__ import main
from training.buffer import ReplayBuffer
from training.checkpoint import load_checkpoint, read_config, read_counters
from training.config import Config
from training.lab.throughput import PlainLearner
from training.learner import Learner
from training.networks import network_classes, network_from_config
from training.networks.stacked import flatten_weights, seed_network, stack_network
from training.networks.terl import ValidTokens, capacity_of
from training.acting import TransitionStore, epsilon_greedy
from training.seed_state import METRICS_FILE, SeedFailed, SeedRun
from training.train import train_seeds


def tiny(**changes) -> Config:
    return Config.of(model="terl", hidden=16, layers=1, heads=2, batch_size=32).replace(**changes)


def small_buffer(config: Config) -> ReplayBuffer:
    """Transitions of small-15 (8 evader slots) from random-ish play."""
    buffer = ReplayBuffer(2_000, evader_slots=8)
    rng = np.random.default_rng(0)
    scenario = Scenario.preset("small-15")
    rollout = Rollout(World(scenario, 2, seed=1))
    store = TransitionStore(buffer, config.data, config.learner.gamma, 2 * scenario.pursuers)
    model = network_from_config(config.network)
    for _ in range(6):
        turn = rollout.turn()
        states = turn.observation.rows(turn.rows).as_inputs()
        step = rollout.step(epsilon_greedy(model, states, 0.5, rng))
        store.add(turn.rows, states, step.actions, step.observation, step.result, rng)
    return buffer


def flat(model: torch.nn.Module, grads: bool = False) -> torch.Tensor:
    return torch.cat([(p.grad if grads else p.detach()).reshape(-1) for p in model.parameters()])


def relative(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).abs().max() / b.abs().max())


@pytest.mark.parametrize("model", sorted(network_classes()))
def test_a_stacked_network_gives_every_seed_its_own_outputs(model):
    torch.manual_seed(0)
    config = tiny(model=model, layers=1 if model.startswith("terl") and model != "terl-no-re" else 0,
                  heads=2 if model.startswith("terl") and model != "terl-no-re" else 0)
    networks = [network_from_config(config.network).eval() for _ in range(3)]
    weights = flatten_weights(networks)
    stacked = stack_network(networks[0], weights, trainable=False, bucket=8).eval()
    rows, shapes = 5, {"ego": (4,), "teammates": (5, 7), "evaders": (8, 7), "obstacles": (5, 5)}
    inputs = []
    for _ in networks:
        mask = torch.rand(rows, 19) < 0.5
        mask[:, 0] = True
        inputs.append([torch.randn(rows, *shape) for shape in shapes.values()] + [mask])
    taus = torch.rand(3 * rows, 8)
    together = stacked(*[torch.cat(parts) for parts in zip(*inputs)], taus).quantiles
    for k, network in enumerate(networks):
        alone = network(*inputs[k], taus[k * rows:(k + 1) * rows]).quantiles
        torch.testing.assert_close(together[k * rows:(k + 1) * rows], alone, rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(seed_network(networks[0], weights, k).eval()(*inputs[k], taus[k * rows:(k + 1) * rows]).quantiles, alone)


@pytest.mark.parametrize("seeds", [1, 2, 3, 4])
def test_each_seed_of_a_stack_updates_as_it_would_alone(seeds):
    # The clip bites (a small max_grad_norm): each seed's own norm must scale its own gradients.
    config = tiny(max_grad_norm=0.05, learning_rate=1e-3)
    buffer = small_buffer(config)
    rng = np.random.default_rng(1)
    learner = Learner(config.network, config.learner, list(range(1, seeds + 1)))
    fractions = [generator.get_state() for generator in learner.generators]
    for _ in range(2):  # two steps: Adam's moments and step count carry over
        batches = [buffer.sample(32, rng) for _ in range(seeds)]
        losses = learner.update(batches)
    for k in range(seeds):
        alone = PlainLearner(config, k + 1)  # the update of main 7725bd1, on the same batches and fractions
        alone.generator.set_state(fractions[k])
        rng = np.random.default_rng(1)
        for _ in range(2):
            batches = [buffer.sample(32, rng) for _ in range(seeds)]
            loss = alone.update([batches[k]])
        assert loss == pytest.approx(losses[k].item(), rel=1e-5)
        assert relative(learner.gradients[k], flat(alone.model, grads=True)) < 1e-5
        assert relative(learner.weights[k], flat(alone.model)) < 1e-5


def test_a_stack_of_several_seeds_lies_whole_on_its_device():
    # The meta device stands in for a GPU here: a stack built on another device than the CPU
    # must move every seed's weights there, not the first seed's alone.
    config = tiny()
    learner = Learner(config.network, dataclasses.replace(config.learner, device="meta"), [1, 2, 3])
    tensors = [learner.weights, learner.target_weights, learner.gradients, *learner.template.parameters()]
    assert {tensor.device.type for tensor in tensors} == {"meta"}


needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(),
                                reason="needs a CUDA GPU (a device machine: scripts/device-grid.sh runs these first)")


@pytest.mark.cuda
@needs_cuda
@pytest.mark.parametrize("seeds", [1, 3])
def test_on_a_gpu_each_seed_of_a_stack_updates_as_on_the_cpu(seeds):
    config = tiny(max_grad_norm=0.05, learning_rate=1e-3)
    buffer = small_buffer(config)
    weights = []
    for device in ("cpu", "cuda"):
        learner = Learner(config.network, dataclasses.replace(config.learner, device=device), list(range(1, seeds + 1)))
        rng = np.random.default_rng(1)
        for _ in range(2):
            learner.update([buffer.sample(32, rng) for _ in range(seeds)])
        weights.append(learner.weights.cpu())
    assert relative(weights[1], weights[0]) < 1e-4


@pytest.mark.cuda
@needs_cuda
def test_on_a_gpu_seeds_trained_together_checkpoint_and_resume(tmp_path):
    runs = [SeedRun(seed, tmp_path / f"seed-{seed}") for seed in (1, 2)]
    train_seeds(run_config(device="cuda"), runs, show_progress=False)
    resumed = [SeedRun(run.seed, run.out_dir, run.out_dir) for run in runs]
    counters = train_seeds(run_config(device="cuda", total_steps=400), resumed, show_progress=False)
    assert {seed: c.env_step for seed, c in counters.items()} == {1: 400, 2: 400}
    assert all((run.out_dir / "best" / "state.json").is_file() for run in runs)


def test_a_seeds_networks_start_as_a_one_seed_run_of_that_seed_draws_them():
    config = tiny()
    learner = Learner(config.network, config.learner, [3, 7])
    for k, seed in enumerate((3, 7)):
        torch.manual_seed(seed)
        alone = network_from_config(config.network)
        assert torch.equal(flat(alone), learner.weights[k]) and torch.equal(flat(alone), learner.target_weights[k])


def test_a_seeds_state_reads_as_a_one_seed_checkpoint_and_loads_back():
    config = tiny()
    buffer = small_buffer(config)
    rng = np.random.default_rng(2)
    learner = Learner(config.network, config.learner, [1, 2])
    learner.update([buffer.sample(32, rng), buffer.sample(32, rng)])
    online, target, optimizer = learner.seed_state(1)
    model = network_from_config(config.network)
    model.load_state_dict(online)
    plain = torch.optim.Adam(model.parameters(), lr=config.learner.learning_rate)
    plain.load_state_dict(optimizer)  # the layout of a one-seed run's optimizer.pt
    assert torch.equal(flat(model), learner.weights[1])
    other = Learner(config.network, config.learner, [5, 6])
    other.load_seed_state(0, online, target, optimizer)
    assert torch.equal(other.weights[0], learner.weights[1]) and torch.equal(other.target_weights[0], learner.target_weights[1])
    assert torch.equal(other.optimizer.states[0]["exp_avg_sq"], learner.optimizer.states[1]["exp_avg_sq"])


def test_a_stack_that_keeps_some_seeds_updates_them_as_before():
    config = tiny()
    buffer = small_buffer(config)
    learner = Learner(config.network, config.learner, [1, 2, 3])
    learner.update([buffer.sample(32, np.random.default_rng(k)) for k in range(3)])
    reference = Learner(config.network, config.learner, [1, 2, 3])
    reference.update([buffer.sample(32, np.random.default_rng(k)) for k in range(3)])
    learner.keep([0, 2])
    assert learner.seeds == [1, 3] and learner.size == 2 and len(learner.online) == 2
    batches = [buffer.sample(32, np.random.default_rng(9)) for _ in range(3)]
    learner.update([batches[0], batches[2]])
    reference.update(batches)
    assert relative(learner.weights[1], reference.weights[2]) < 1e-5


def test_on_a_device_whose_counts_cannot_be_read_without_waiting_every_token_is_kept():
    # A GPU's counts would need a host sync: there every seed keeps all its rows (no read).
    assert capacity_of(torch.tensor([5, 9], device="meta"), 8, 40) == 40
    assert capacity_of(torch.tensor([5, 9]), 8, 40) == 16
    mask = torch.tensor([[True, False, True, True], [True, True, False, False]])
    valid = ValidTokens(mask, seeds=2, bucket=4)  # seed 0: tokens 0, 2, 3; seed 1: tokens 4, 5
    assert valid.rows.tolist()[:3] == [0, 2, 3] and valid.rows.tolist()[4:6] == [4, 5]
    rows = torch.arange(8.0)[:, None]  # the 2 x 4 gathered rows
    assert valid.spread(valid.gather(torch.arange(8.0)[:, None])).squeeze(1).tolist() == [0, 0, 2, 3, 4, 5, 0, 0]
    assert rows.shape == (8, 1)


def run_config(**changes) -> Config:
    return tiny(total_steps=320, num_envs=4, learning_starts=80, buffer_size=5_000, target_network_frequency=160,
                eval_max_steps=10, snapshot_frequency=160, snapshot_episodes=1, log_frequency=160,
                checkpoint_frequency=160).replace(**changes)


def records(folder, kind):
    return [json.loads(line) for line in (folder / METRICS_FILE).read_text().splitlines() if json.loads(line)["kind"] == kind]


def test_seeds_trained_together_each_lay_out_a_one_seed_run_on_one_schedule(tmp_path):
    runs = [SeedRun(seed, tmp_path / f"seed-{seed}") for seed in (1, 2)]
    counters = train_seeds(run_config(), runs, show_progress=False)
    assert sorted(counters) == [1, 2]
    for run in runs:
        assert read_counters(run.out_dir).env_step == 320 and read_config(run.out_dir).run.seed == run.seed
        assert (run.out_dir / "best" / "state.json").is_file() and (run.out_dir / "replay.npz").is_file()
    schedules = [[(r["env_step"], r["updates"], r["epsilon"], r["learning_rate"], r["stage"]) for r in records(run.out_dir, "train")]
                 for run in runs]
    assert schedules[0] == schedules[1] and len(schedules[0]) == 2
    assert not torch.equal(load_checkpoint(runs[0].out_dir).online["head.out.weight"],
                           load_checkpoint(runs[1].out_dir).online["head.out.weight"])
    resumed = [SeedRun(run.seed, run.out_dir, run.out_dir) for run in runs]
    counters = train_seeds(run_config(total_steps=400), resumed, show_progress=False)
    assert {seed: c.env_step for seed, c in counters.items()} == {1: 400, 2: 400}
    assert all(records(run.out_dir, "resume") for run in runs)


def test_seeds_trained_together_resume_from_one_step_only(tmp_path):
    train_seeds(run_config(total_steps=80, snapshot_frequency=0), [SeedRun(1, tmp_path / "a")], show_progress=False)
    train_seeds(run_config(total_steps=40, snapshot_frequency=0), [SeedRun(2, tmp_path / "b")], show_progress=False)
    with pytest.raises(ValueError, match="resume from one environment step"):
        train_seeds(run_config(total_steps=480), [SeedRun(1, tmp_path / "a", tmp_path / "a"),
                                                  SeedRun(2, tmp_path / "b", tmp_path / "b")], show_progress=False)


def test_a_seed_whose_loss_turns_non_finite_stops_alone(tmp_path, monkeypatch, capfd):
    update = Learner.update

    def poisoned(self, batches, trim=True):
        if 2 in self.seeds:
            self.weights[self.seeds.index(2)].fill_(float("nan"))  # seed 2 diverges
        return update(self, batches, trim)

    monkeypatch.setattr(Learner, "update", poisoned)
    runs = [SeedRun(seed, tmp_path / f"seed-{seed}") for seed in (1, 2)]
    counters = train_seeds(run_config(), runs, show_progress=True)
    assert list(counters) == [1] and counters[1].env_step == 320
    assert "Error: seed 2: a non-finite loss at environment step" in capfd.readouterr().err
    assert not (tmp_path / "seed-2" / "state.json").exists()  # no checkpoint of NaN weights
    with pytest.raises(SeedFailed, match="every seed stopped"):
        train_seeds(run_config(), [SeedRun(2, tmp_path / "again")], show_progress=False)


def test_run_with_seeds_takes_no_seed_beside_it_and_runs_the_segments_asked(tmp_path, capsys):
    # Each seed's policy in its own folder: test_grid.py's grid trains every method's seeds together.
    assert main(["run", "tests/data/tiny-recipe.toml", "--out", str(tmp_path / "x"), "--seeds", "1", "--seed", "2"]) == 2
    assert "not both" in capsys.readouterr().err
    assert main(["run", "tests/data/tiny-recipe.toml", "--out", str(tmp_path / "part"), "--seeds", "3", "--segments", "1",
                 "--quiet"]) == 0
    assert (tmp_path / "part" / "seed-3" / "1-curriculum" / "state.json").is_file()
    assert not (tmp_path / "part" / "seed-3" / "2-small").exists() and "nothing exported" in capsys.readouterr().out
