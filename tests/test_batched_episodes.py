"""Batched evaluation (issue 40): the episodes of a preset run together in one World, each
one bit for bit the episode `Simulator(scenario, seed)` runs alone, logs included."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from onnx_models import write_test_policy
from tiny_worlds import capture_scenario

from terl_rt.evaluation.evaluate import evaluate_policy
from terl_rt.evaluation.play import batch_steps, run_episode
from terl_rt.evaluation.runs import EpisodeSpec, batches
from terl_rt.logs.writer import EpisodeLogWriter
from terl_rt.policy.onnx_policy import OnnxPolicy, policy_info
from terl_rt.sim.rollout import Rollout
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.world import World

SHIPPED = Path(__file__).resolve().parent.parent / "exported" / "terl.onnx"


@pytest.fixture(scope="module")
def shipped() -> OnnxPolicy:
    return OnnxPolicy(SHIPPED, threads=1)


def ended_apart() -> Scenario:
    """small-15 cut at 75 steps: with the shipped policy, seeds 0-5 end at 50 to 75 steps,
    by capture, by the limit and one with a collision, so slots restart and drop."""
    return Scenario.preset("small-15").replace(max_steps=75)


def same(a, b) -> bool:
    """Equal bit for bit: arrays by dtype and value, dataclasses and dicts field by field."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return np.asarray(a).dtype == np.asarray(b).dtype and np.array_equal(a, b)
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if dataclasses.is_dataclass(a):
        return type(a) is type(b) and all(same(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a))
    return a == b


def by_episode(messages) -> dict[int, list]:
    out: dict[int, list] = {}
    for kind, j, payload in messages:
        out.setdefault(j, []).append((kind, payload))
    return out


def test_every_batched_episode_is_the_one_it_runs_alone(shipped):
    scenario, seeds = ended_apart(), [0, 1, 2, 3, 4, 5]
    batched = by_episode(batch_steps(shipped, scenario, seeds, envs=3))
    lengths = set()
    for j, seed in enumerate(seeds):
        alone = by_episode(batch_steps(shipped, scenario, [seed], envs=1))[0]
        assert len(batched[j]) == len(alone), f"episode {j}: {len(batched[j])} messages batched, {len(alone)} alone"
        assert all(kb == ka and same(pb, pa) for (kb, pb), (ka, pa) in zip(batched[j], alone)), f"episode {j} differs"
        lengths.add(alone[-1][1].steps)
    assert len(lengths) > 2  # the episodes ended apart: slots restarted and were dropped


def test_batched_evaluation_writes_the_log_of_episodes_run_alone(shipped, tmp_path):
    scenario = ended_apart()
    result = evaluate_policy(shipped, scenario, episodes=5, seed=10, log_path=tmp_path / "batched.mcap")
    with EpisodeLogWriter(tmp_path / "alone.mcap", policy_info(shipped)) as log:
        for k in range(5):
            log.begin_episode(scenario, 10 + k, k)
            metrics = run_episode(shipped, scenario, 10 + k, log.write_step)
            log.end_episode(metrics)
            assert metrics == result.per_episode[k]
    assert (tmp_path / "batched.mcap").read_bytes() == (tmp_path / "alone.mcap").read_bytes()


def test_a_rows_outputs_do_not_depend_on_the_rows_beside_it(shipped):
    observation = World(Scenario.preset("small-15"), num_envs=2, seed=3).reset()
    everyone = shipped.evaluate(observation.rows(np.arange(30)))
    for rows in (np.array([4]), np.array([4, 5]), np.arange(17)):
        part = shipped.evaluate(observation.rows(rows))
        assert np.array_equal(part.q_values, everyone.q_values[rows])
        assert np.array_equal(part.target_weights, everyone.target_weights[rows])


def test_rollout_with_seeds_runs_each_episode_once_then_drops_idle_environments():
    # capture_scenario(3): every episode lasts 3 steps; 5 episodes on 2 environments.
    world = World(capture_scenario(max_steps=3), num_envs=2)
    rollout = Rollout(world, seeds=np.arange(100, 105))
    ended, sizes = [], []
    while not rollout.finished:
        turn = rollout.turn()
        sizes.append(world.num_envs)
        step = rollout.step(np.zeros(len(turn.rows), np.int64))
        ended += [int(turn.episodes[env]) for env in step.outcomes]
    assert sorted(ended) == [0, 1, 2, 3, 4]
    assert sizes == [2] * 6 + [1] * 3  # episodes 0-3 two at a time, then episode 4 alone
    with pytest.raises(RuntimeError, match="ended"):
        rollout.turn()


def test_reseeded_environment_starts_the_episode_of_a_simulator_with_that_seed():
    scenario = Scenario.preset("small-11")
    world, alone = World(scenario, num_envs=3, seed=0), World(scenario, num_envs=1, seed=42)
    world.reseed(np.array([2]), np.array([42]))
    world.reset()
    alone.reset()
    assert np.array_equal(world.state.pursuer_xy[2], alone.state.pursuer_xy[0])
    assert np.array_equal(world.state.obstacle_r[2], alone.state.obstacle_r[0])


def test_kept_environments_step_on_as_before_and_the_others_are_dropped():
    scenario = Scenario.preset("small-11")
    full, cut = World(scenario, num_envs=3, seed=7), World(scenario, num_envs=3, seed=7)
    full.reset()
    cut.reset()
    cut.keep(np.array([0, 2]))
    assert cut.num_envs == 2 and cut.state.pursuer_xy.shape[0] == 2
    actions = np.random.default_rng(0).integers(0, 9, (3, 11))
    full_obs, _ = full.step(actions)
    cut_obs, _ = cut.step(actions[[0, 2]])
    assert np.array_equal(cut.state.pursuer_xy, full.state.pursuer_xy[[0, 2]])
    assert np.array_equal(cut_obs.evaders, full_obs.evaders[[0, 2]])
    with pytest.raises(ValueError, match="ascending"):
        cut.keep(np.array([1, 0]))


def test_batches_split_each_preset_over_the_workers_in_turn():
    small, large = Scenario.preset("small-11"), Scenario.preset("large-80")
    specs = [EpisodeSpec(0, small, k, k) for k in range(5)] + [EpisodeSpec(0, large, k, k) for k in range(2)]
    assert batches(specs, 2) == [[0, 2, 4], [1, 3], [5], [6]]
    assert batches(specs, 1) == [[0, 1, 2, 3, 4], [5, 6]]
    assert batches(specs, 8) == [[0], [1], [2], [3], [4], [5], [6]]


def test_batch_asked_to_stop_ends_before_its_next_step(tmp_path):
    policy = OnnxPolicy(write_test_policy(tmp_path / "linear.onnx"))
    asked = []
    stop = lambda: asked.append(1) or len(asked) > 2  # noqa: E731 (true from the third step on)
    steps = [record.step for kind, _, record in batch_steps(policy, capture_scenario(5), [0, 1], stop=stop)]
    assert steps == [0, 0, 1, 1, 2, 2]  # two steps of both episodes, neither ended
