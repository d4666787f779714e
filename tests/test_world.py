"""World and Simulator contracts: determinism, partial reset, episode ends, API errors (world.md section 10)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from sim_helpers import PURSUER_IDLE, far_row, idle_evader, initial_scenario, ring

from terl_rt.sim.scenario import Scenario
from terl_rt.sim.simulator import Simulator
from terl_rt.sim.state import WorldState
from terl_rt.sim.world import World

STATE_FIELDS = [f.name for f in dataclasses.fields(WorldState)]


def random_actions(rng: np.random.Generator, shape) -> np.ndarray:
    return rng.integers(0, 9, shape)


def assert_same_env(a: WorldState, b: WorldState, env_a: int, env_b: int | None = None) -> None:
    env_b = env_a if env_b is None else env_b
    for name in STATE_FIELDS:
        assert np.array_equal(getattr(a, name)[env_a], getattr(b, name)[env_b]), name


def quiet_scenario(**fields) -> Scenario:
    """Three parked pursuers and one parked evader far apart: nothing happens but time."""
    return initial_scenario(
        pursuers=[far_row(0, y=20.0), far_row(1, y=20.0), far_row(2, y=20.0)],
        evaders=[[60.0, 90.0, 0.0, 0.0]],
        **fields,
    )


def ring_scenario(**fields) -> Scenario:
    """One evader at (50, 50) inside an even ring of three pursuers (6 m): encircled at the first step."""
    return initial_scenario(pursuers=ring((50.0, 50.0), 6.0, [0, 120, 240]), evaders=[[50.0, 50.0, 0.0, 0.0]],
                            **fields)


def crash_scenario(**fields) -> Scenario:
    """Pursuers 0 and 1 start 2.5 m apart (just clear of each other) driving head-on at 2 m/s
    and collide at the first step; 1 of 3 remains."""
    return initial_scenario(
        pursuers=[[30.0, 30.0, 0.0, 2.0], [32.5, 30.0, math.pi, 2.0], far_row(0)],
        evaders=[[90.0, 60.0, 0.0, 0.0]],
        **fields,
    )


# ---------------------------------------------------------------- determinism
def rollout(seed: int, steps: int = 12, num_envs: int = 2):
    world = World(Scenario.preset("small-11"), num_envs=num_envs, seed=seed)
    rng = np.random.default_rng(100)
    frames = [world.reset()]
    for _ in range(steps):
        obs, result = world.step(random_actions(rng, (num_envs, 11)))
        frames += [obs, result]
        if world.done.any():
            frames.append(world.reset(env_mask=world.done))
    return world, frames


def test_same_seed_and_actions_give_the_same_rollout_bit_for_bit():
    world_a, frames_a = rollout(seed=7)
    world_b, frames_b = rollout(seed=7)
    assert_same_env(world_a.state, world_b.state, 0)
    assert_same_env(world_a.state, world_b.state, 1)
    for fa, fb in zip(frames_a, frames_b, strict=True):
        for f in dataclasses.fields(fa):
            assert np.array_equal(getattr(fa, f.name), getattr(fb, f.name)), f.name


def test_different_seeds_give_different_worlds():
    a, b = World(Scenario.preset("small-11"), seed=1), World(Scenario.preset("small-11"), seed=2)
    a.reset()
    b.reset()
    assert not np.array_equal(a.state.pursuer_xy, b.state.pursuer_xy)
    assert not np.array_equal(a.state.evader_xy, b.state.evader_xy)


def test_environments_of_one_batch_differ():
    world = World(Scenario.preset("small-11"), num_envs=2, seed=1)
    world.reset()
    assert not np.array_equal(world.state.pursuer_xy[0], world.state.pursuer_xy[1])


def test_world_env_0_replays_as_simulator_with_the_same_seed():
    scenario = Scenario.preset("small-15")
    world, sim = World(scenario, num_envs=3, seed=5), Simulator(scenario, seed=5)
    world_obs, sim_obs = world.reset(), sim.reset()
    rng = np.random.default_rng(0)
    for _ in range(10):
        assert np.array_equal(world_obs.ego[0, sim_obs.pursuer_index], sim_obs.ego)
        assert np.array_equal(world_obs.mask[0, sim_obs.pursuer_index], sim_obs.mask)
        actions = random_actions(rng, (3, 15))
        world_obs, result = world.step(actions)
        sim_obs, info = sim.step(actions[0])
        assert np.array_equal(result.reward[0], info.reward)
        state = sim.state()
        for name in ("pursuer_xy", "pursuer_theta", "pursuer_speed", "pursuer_vel", "evader_xy", "evader_vel",
                     "evader_active", "pursuer_active"):
            assert np.array_equal(getattr(world.state, name)[0], state[name]), name
        if world.done.any() or sim.done:
            break


def test_env_rows_do_not_depend_on_batch_size():
    small, large = World(Scenario.preset("small-11"), num_envs=2, seed=9), World(Scenario.preset("small-11"), num_envs=4, seed=9)
    small.reset()
    large.reset()
    assert_same_env(small.state, large.state, 1)


def test_reset_with_seed_restarts_the_stream():
    sim = Simulator(Scenario.preset("small-11"), seed=0)
    sim.reset(seed=3)
    first = sim.state()
    sim.reset()
    assert not np.array_equal(sim.state()["pursuer_xy"], first["pursuer_xy"])  # the next episode differs
    sim.reset(seed=3)
    for name, value in sim.state().items():
        assert np.array_equal(value, first[name]), name


# ---------------------------------------------------------------- partial reset
def stepped_world(num_envs: int = 3) -> World:
    world = World(Scenario.preset("small-11"), num_envs=num_envs, seed=4)
    world.reset()
    rng = np.random.default_rng(1)
    for _ in range(3):
        world.step(random_actions(rng, (num_envs, 11)))
    assert not world.done.any()
    return world


def test_partial_reset_leaves_other_envs_untouched():
    world = stepped_world()
    before = world.state.copy()
    obs = world.reset(env_mask=np.array([False, True, False]))
    assert obs.ego.shape == (3, 11, 4)
    assert_same_env(world.state, before, 0)
    assert_same_env(world.state, before, 2)
    assert world.state.steps.tolist() == [3, 0, 3]
    assert not np.array_equal(world.state.pursuer_xy[1], before.pursuer_xy[1])


def test_partial_reset_does_not_draw_from_other_envs_generators():
    # env 0's next episode is the same whether or not env 1 was reset in between
    a, b = World(Scenario.preset("small-11"), num_envs=2, seed=4), World(Scenario.preset("small-11"), num_envs=2, seed=4)
    a.reset()
    b.reset()
    a.reset(env_mask=np.array([False, True]))
    a.reset(env_mask=np.array([True, False]))
    b.reset(env_mask=np.array([True, False]))
    assert_same_env(a.state, b.state, 0)


def test_partial_reset_clears_done_only_for_its_envs():
    world = World(quiet_scenario(max_steps=1), num_envs=2, evader_policy=idle_evader())
    world.reset()
    world.step(np.full((2, 3), PURSUER_IDLE))
    assert world.done.tolist() == [True, True]
    world.reset(env_mask=np.array([True, False]))
    assert world.done.tolist() == [False, True]
    with pytest.raises(RuntimeError, match=r"\[1\]"):
        world.step(np.full((2, 3), PURSUER_IDLE))


def test_first_reset_must_start_every_env():
    with pytest.raises(ValueError, match="first reset"):
        World(Scenario.preset("small-11"), num_envs=2).reset(env_mask=np.array([True, False]))


def test_reset_seed_with_env_mask_raises():
    world = World(Scenario.preset("small-11"), num_envs=2)
    world.reset()
    with pytest.raises(ValueError, match="seed"):
        world.reset(env_mask=np.array([True, False]), seed=1)


def test_reset_env_mask_of_wrong_shape_raises():
    world = World(Scenario.preset("small-11"), num_envs=2)
    world.reset()
    with pytest.raises(ValueError, match="env_mask"):
        world.reset(env_mask=np.array([True, False, True]))


def test_num_envs_must_be_positive():
    with pytest.raises(ValueError, match="num_envs"):
        World(Scenario.preset("small-11"), num_envs=0)


# ---------------------------------------------------------------- episode ends
def test_step_limit_truncates_and_never_terminates():
    sim = Simulator(quiet_scenario(max_steps=3), evader_policy=idle_evader())
    sim.reset()
    for expected_done in (False, False, True):
        _, info = sim.step(np.full(3, PURSUER_IDLE))
        assert info.terminated is False
        assert info.truncated is expected_done
        assert sim.done is expected_done
    assert not sim.success


def test_fewer_than_three_pursuers_terminates_and_does_not_truncate():
    # also at the step limit: terminated wins, truncated stays False
    sim = Simulator(crash_scenario(max_steps=1), evader_policy=idle_evader())
    sim.reset()
    _, info = sim.step(np.full(3, PURSUER_IDLE))
    assert info.collided.tolist() == [True, True, False]
    assert (info.terminated, info.truncated) == (True, False)
    assert sim.done and not sim.success


def test_every_evader_encircled_terminates_with_success():
    world = World(ring_scenario(max_steps=1), evader_policy=idle_evader())
    world.reset()
    _, result = world.step(np.full((1, 3), PURSUER_IDLE))
    assert result.captured.tolist() == [[True]]
    assert result.terminated.tolist() == [True]
    assert result.truncated.tolist() == [False]
    assert result.success.tolist() == [True]
    assert world.metrics().success


def test_step_after_done_raises():
    sim = Simulator(quiet_scenario(max_steps=1), evader_policy=idle_evader())
    sim.reset()
    sim.step(np.full(3, PURSUER_IDLE))
    with pytest.raises(RuntimeError, match="reset"):
        sim.step(np.full(3, PURSUER_IDLE))


def test_step_before_reset_raises():
    with pytest.raises(RuntimeError, match="reset"):
        World(Scenario.preset("small-11")).step(np.zeros((1, 11), np.int64))


def test_simulator_is_done_before_the_first_reset():
    assert Simulator(Scenario.preset("small-11")).done


# ---------------------------------------------------------------- actions
@pytest.mark.parametrize(
    ("actions", "problem"),
    [
        (np.full(4, PURSUER_IDLE), "shape"),
        (np.full((1, 3), PURSUER_IDLE), "shape"),
        (np.full(3, 4.0), "integer"),
        (np.array([4, 9, 4]), r"\[0, 9\)"),
        (np.array([4, -1, 4]), r"\[0, 9\)"),
    ],
)
def test_invalid_simulator_actions_raise_naming_the_problem(actions, problem):
    sim = Simulator(quiet_scenario(), evader_policy=idle_evader())
    sim.reset()
    with pytest.raises(ValueError, match=rf"pursuer_actions.*{problem}"):
        sim.step(actions)


def test_invalid_world_actions_raise_naming_the_shape():
    world = World(quiet_scenario(), num_envs=2, evader_policy=idle_evader())
    world.reset()
    with pytest.raises(ValueError, match=r"pursuer_actions.*\(2, 3\)"):
        world.step(np.full((2, 2), PURSUER_IDLE))


def test_actions_of_collided_pursuers_are_ignored():
    scenario = initial_scenario(
        pursuers=[[30.0, 30.0, 0.0, 2.0], [32.5, 30.0, math.pi, 2.0], far_row(0), far_row(1), far_row(2)],
        evaders=[[90.0, 60.0, 0.0, 0.0]],
    )
    sim = Simulator(scenario, evader_policy=idle_evader())
    sim.reset()
    sim.step(np.full(5, PURSUER_IDLE))
    _, info = sim.step(np.array([99, -7, PURSUER_IDLE, PURSUER_IDLE, PURSUER_IDLE]))
    assert info.reward[:2].tolist() == [0.0, 0.0]


def test_evader_policy_of_wrong_shape_raises():
    class Broken:
        def act(self, state, geometry, params, arena):
            return np.zeros((1, 5), np.int64)

    world = World(quiet_scenario(), evader_policy=Broken())
    world.reset()
    with pytest.raises(ValueError, match="evader policy"):
        world.step(np.full((1, 3), PURSUER_IDLE))


@pytest.mark.parametrize("evader_policy", [object(), "apf"], ids=["object", "name"])
def test_an_evader_policy_without_act_is_a_type_error_naming_it(evader_policy):
    with pytest.raises(TypeError, match=r"evader_policy must have an act\(state, geometry, params, arena\) method"):
        World(quiet_scenario(), evader_policy=evader_policy)


# ---------------------------------------------------------------- results, state and metrics
def test_step_result_shapes_and_dtypes():
    world = World(Scenario.preset("small-11"), num_envs=2, seed=0)
    world.reset()
    _, r = world.step(np.full((2, 11), PURSUER_IDLE))
    assert r.reward.shape == (2, 11) and r.reward.dtype == np.float64
    assert r.reward_terms.shape == (2, 11, 7)
    for name in ("acted", "collided"):
        assert getattr(r, name).shape == (2, 11) and getattr(r, name).dtype == np.bool_
    assert r.captured.shape == (2, 3) and r.evader_actions.shape == (2, 3)
    assert r.pursuer_target.shape == (2, 11)
    for name in ("terminated", "truncated", "success"):
        assert getattr(r, name).shape == (2,) and getattr(r, name).dtype == np.bool_
    assert world.state.steps.tolist() == [1, 1]


def test_simulator_state_is_a_copy():
    sim = Simulator(Scenario.preset("small-11"), seed=0)
    sim.reset()
    state = sim.state()
    state["pursuer_xy"][:] = -1.0
    assert np.all(sim.state()["pursuer_xy"] >= 0.0)
    assert state["step"] == 0
    assert state["pursuer_collided"].tolist() == [False] * 11


def test_metrics_count_time_collisions_and_captures():
    scenario = initial_scenario(
        pursuers=[[30.0, 30.0, 0.0, 2.0], [32.5, 30.0, math.pi, 2.0], far_row(0), far_row(1), far_row(2)],
        evaders=[[90.0, 60.0, 0.0, 0.0]],
    )
    sim = Simulator(scenario, evader_policy=idle_evader())
    sim.reset()
    for _ in range(3):
        sim.step(np.full(5, PURSUER_IDLE))
    m = sim.metrics()
    assert (m.steps, m.pursuers_collided, m.evaders_encircled) == (3, 2, 0)
    assert m.travel_time_s == pytest.approx(1.5)  # 3 decision steps of 0.5 s
    assert m.collision_ratio == pytest.approx(2 / 5)
    assert not m.success
    assert m.to_dict()["steps"] == 3


# ---------------------------------------------------------------- presets
@pytest.mark.parametrize("name", Scenario.presets())
def test_every_preset_resets_and_steps(name):
    scenario = Scenario.preset(name)
    world = World(scenario, num_envs=2, seed=0)
    obs = world.reset()
    assert obs.ego.shape == (2, scenario.pursuers, 4)
    assert obs.evaders.shape == (2, scenario.pursuers, scenario.evader_slots, 7)
    rng = np.random.default_rng(0)
    for _ in range(2):
        obs, result = world.step(random_actions(rng, (2, scenario.pursuers)))
    for group in (obs.ego, obs.teammates, obs.evaders, obs.obstacles):
        assert np.all(np.isfinite(group))
    assert np.all(np.isfinite(result.reward))
    assert np.all((world.state.pursuer_theta >= 0) & (world.state.pursuer_theta < 2 * np.pi))
