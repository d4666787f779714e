"""The autoreset loop (terl_rt.sim.rollout): scatter, step, keep outcomes, restart."""

from __future__ import annotations

import numpy as np
import pytest
from tiny_worlds import capture_scenario

from terl_rt.sim.rollout import Rollout
from terl_rt.sim.world import World


def test_chosen_actions_go_to_the_deciding_pursuers_and_0_to_the_others():
    # capture_scenario: pursuers 3 and 4 collide in step 1, so 5 of the 7 decide in step 2.
    rollout = Rollout(World(capture_scenario(max_steps=5), num_envs=1, seed=0))
    assert rollout.turn().rows.tolist() == list(range(7))
    rollout.step(np.full(7, 4))
    turn = rollout.turn()
    assert turn.rows.tolist() == [0, 1, 2, 5, 6]
    assert turn.observation.rows(turn.rows).pursuer_index.tolist() == [0, 1, 2, 5, 6]
    step = rollout.step(np.array([8, 7, 6, 5, 4]))
    assert step.actions.tolist() == [[8, 7, 6, 0, 0, 5, 4]]


def test_rows_count_pursuers_of_every_environment():
    world = World(capture_scenario(), num_envs=2, seed=0)
    rollout = Rollout(world)
    assert rollout.turn().rows.tolist() == list(range(14))  # b * 7 + n
    step = rollout.step(np.arange(14) % 9)
    assert step.actions.tolist() == (np.arange(14) % 9).reshape(2, 7).tolist()


def test_an_ended_episode_keeps_its_outcome_and_restarts_at_the_next_turn():
    world = World(capture_scenario(max_steps=2), num_envs=2, seed=0)
    rollout = Rollout(world)
    for _ in range(2):
        step = rollout.step(np.zeros(len(rollout.turn().rows), np.int64))
    assert sorted(step.outcomes) == [0, 1] and step.outcomes[0].steps == 2
    assert step.outcomes[0] == world.metrics(0)  # the ended state stays until the next turn
    turn = rollout.turn()
    assert turn.restarted.tolist() == [0, 1]
    assert world.state.steps.tolist() == [0, 0] and not world.done.any()
    assert rollout.turn().restarted.tolist() == []


def test_step_needs_a_turn_and_one_action_per_deciding_pursuer():
    rollout = Rollout(World(capture_scenario(), num_envs=1, seed=0))
    with pytest.raises(RuntimeError, match="turn"):
        rollout.step(np.zeros(7, np.int64))
    rollout.turn()
    with pytest.raises(ValueError, match=r"expected shape \(7,\)"):
        rollout.step(np.zeros(6, np.int64))
    with pytest.raises(ValueError, match="integer"):
        rollout.step(np.zeros(7))
