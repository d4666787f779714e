"""The published world, exactly (world.md sections 2, 6, 7 and 9's `published` reward).

Episodes recorded from the published simulator (tests/data/published, format in its
README) are replayed action for action; hand-made worlds pin each corrected rule.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from sim_helpers import DEFAULT, PURSUER_IDLE, far_row, geometry_of, initial_scenario, make_state, ring

from terl_rt.sim.encirclement import encircle, remember_perceived
from terl_rt.sim.evader import ConstantEvader, _repulsion
from terl_rt.sim.reward import REWARD_TERMS, first_perceived_obstacle_distance, published_reward_terms
from terl_rt.sim.scenario import Scenario, ScenarioError
from terl_rt.sim.world import World

RECORDED = Path(__file__).parent / "data" / "published"
EPISODES = sorted(RECORDED.glob("*.json"))
EVADER_STILL = 2
"""evader action (a = -0.4, w = 0): a robot at rest stays at rest."""
PURSUER_AHEAD = 7
"""pursuer action (a = +0.4, w = 0)."""


def recorded(path: Path) -> dict:
    return json.loads(path.read_text())


def replay(episode: dict):
    """Step a world with the recorded actions; yields (t, world, observation, step result, acted)."""
    scenario = Scenario.from_dict(episode["scenario"]).replace(reward="published")
    world = World(scenario)
    observation = world.reset()
    yield 0, world, observation, None, None
    for t, actions in enumerate(episode["actions"]):
        acted = world.state.pursuer_active[0].copy()
        observation, result = world.step(np.array([actions]))
        yield t + 1, world, observation, result, acted


def test_the_recorded_episodes_are_all_here():
    assert len(EPISODES) == 8
    assert sum("observations" in path.name for path in EPISODES) == 2


@pytest.mark.parametrize("path", EPISODES, ids=lambda p: p.stem)
def test_recorded_episode_positions_and_active_flags_agree(path):
    episode = recorded(path)
    for t, world, _, _, acted in replay(episode):
        if t == 0:
            continue
        state = world.state
        np.testing.assert_allclose(state.pursuer_xy[0][acted], np.array(episode["pursuer_xy"][t - 1])[acted], rtol=0, atol=1e-9)
        np.testing.assert_allclose(state.evader_xy[0], episode["evader_xy"][t - 1], rtol=0, atol=1e-9)
        assert state.pursuer_active[0].tolist() == episode["pursuer_active"][t - 1], f"step {t}"
        assert state.evader_active[0].tolist() == episode["evader_active"][t - 1], f"step {t}"


@pytest.mark.parametrize("path", EPISODES, ids=lambda p: p.stem)
def test_published_reward_agrees_with_the_recorded_rewards(path):
    episode = recorded(path)
    for t, _, _, result, acted in replay(episode):
        if t == 0:
            continue
        # the published env.step also returns numbers for pursuers already gone; nobody learns from them
        np.testing.assert_allclose(result.reward[0][acted], np.array(episode["published_reward"][t - 1])[acted],
                                   rtol=0, atol=1e-9, err_msg=f"step {t}")


@pytest.mark.parametrize("path", [p for p in EPISODES if "observations" in p.name], ids=lambda p: p.stem)
def test_observations_agree_with_the_recorded_observations(path):
    # The published observation of a pursuer that collided in step t is still returned by step t,
    # and the others still see it (world.md section 6); null once it is deactivated.
    episode = recorded(path)
    groups = {"self": "ego", "pursuers": "teammates", "evaders": "evaders", "obstacles": "obstacles"}
    seen_collided_teammate = False
    for t, world, observation, result, _ in replay(episode):
        for i, theirs in enumerate(episode["published_obs"][t]):
            if theirs is None:
                assert t > 0 and not world.state.pursuer_perceived[0, i]
                continue
            for key, name in groups.items():
                np.testing.assert_allclose(getattr(observation, name)[0, i], theirs[key], rtol=0, atol=2e-5,
                                           err_msg=f"step {t}, pursuer {i}, {key}")
            assert observation.mask[0, i].tolist() == theirs["masks"], f"step {t}, pursuer {i}"
        if result is not None and result.collided.any():
            seen_collided_teammate = True
    assert seen_collided_teammate or "less_pursuer" in path.name


# ---------------------------------------------------------------- section 2: velocity at reset
# (tests/test_dynamics.py::test_reset_velocity_is_the_steer_velocity_without_the_current)


# ---------------------------------------------------------------- section 6: timing of a collision
def crash_world():
    """Evader E at rest at (50, 50). p0 and p1 at 6 m (bearings 0, 120) hold still; p2 starts at
    4.5 m (bearing 240), 2.4 m from an obstacle (clear of contact at r + 1.05 = 2.168 m), and drives
    out at 2 m/s: it collides in step 1, close to E. p3, p4 far away."""
    pursuers = ring([50.0, 50.0], 6.0, [0, 120]) + ring([50.0, 50.0], 4.5, [240], theta=math.radians(240), speed=2.0)
    pursuers += [far_row(0), far_row(1)]
    obstacle = ring([50.0, 50.0], 6.9, [240])[0][:2] + [1.05]
    scenario = initial_scenario(pursuers=pursuers, evaders=[[50.0, 50.0, 0.0, 0.0], [100.0, 10.0, 0.0, 0.0]],
                                obstacles=[obstacle], evader_slots=4)
    world = World(scenario, evader_policy=ConstantEvader(EVADER_STILL))
    world.reset()
    return world


ACTIONS = np.full((1, 5), PURSUER_IDLE)


def teammate_distances(observation, pursuer: int) -> np.ndarray:
    present = observation.mask[0, pursuer, 1:6]
    return np.sort(observation.teammates[0, pursuer, present, 4])


def test_pursuer_that_collides_is_still_a_teammate_in_the_observations_of_its_step():
    world = crash_world()
    observation, result = world.step(ACTIONS)
    assert result.collided[0].tolist() == [False, False, True, False, False]
    assert not world.state.pursuer_active[0, 2] and world.state.pursuer_perceived[0, 2]
    xy = world.state.pursuer_xy[0]
    expected = sorted([np.hypot(*(xy[1] - xy[0])), np.hypot(*(xy[2] - xy[0]))])  # p1 and p2
    np.testing.assert_allclose(teammate_distances(observation, 0), expected, rtol=1e-6)
    # from the next step on nobody perceives it
    observation, _ = world.step(ACTIONS)
    assert len(teammate_distances(observation, 0)) == 1
    assert not world.state.pursuer_perceived[0, 2]


def test_evaders_decide_the_next_step_with_the_pursuer_that_collided_in_view():
    # The APF force on E for its step-2 decision includes p2's push; hiding p2 changes it. (Robots
    # push only an evader closing in on them: E is given 1 m/s towards p2.)
    world = crash_world()
    world.step(ACTIONS)
    state, geometry = world.state, world.geometry
    state.evader_vel[0, 0] = [math.cos(math.radians(240)), math.sin(math.radians(240))]
    state.pursuer_vel[0, 2] = 0.0  # p2 drove into the obstacle: held still, E closes in on it
    hidden = state.copy()
    hidden.pursuer_perceived[0, 2] = False
    with_p2, without_p2 = _repulsion(state, geometry, DEFAULT)[0, 0], _repulsion(hidden, geometry, DEFAULT)[0, 0]
    assert abs(with_p2 - without_p2) > 1.0
    # p2 sits towards 240 degrees of E: it pushes E towards 60 degrees
    assert math.degrees(np.angle(with_p2 - without_p2)) == pytest.approx(60.0, abs=15.0)
    # one step later it is gone from the evaders' view too
    world.step(ACTIONS)
    assert world.state.pursuer_perceived[0].tolist() == [True, True, False, True, True]


def test_pursuer_that_collides_counts_in_the_encirclement_test_of_its_step():
    # (tests/test_encirclement.py::test_pursuer_that_collides_in_the_step_still_helps_encircle)
    world = crash_world()
    _, result = world.step(ACTIONS)
    assert result.collided[0, 2]
    # p0 and p1 each have p2 as second helper: the even ring closes in the step p2 collides
    assert result.captured[0].tolist() == [True, False]
    assert result.pursuer_target[0].tolist() == [0, 0, 0, -1, -1]


# ---------------------------------------------------------------- section 7: a crashed pursuer keeps testing
def late_ring_world():
    """E at rest at (50, 50); p2 crashes at 3.5 m from E in step 1 (obstacle, as above) while p0 and
    p1 (bearings 0 and 120) are 10 m out, driving in at 3 m/s: 8.6 m after step 1 (too far to help),
    7.1 m after step 2. Only p2, from where it stopped and with the teammates it saw in step 1,
    closes the ring: p0 and p1 have one live helper each."""
    pursuers = ring([50.0, 50.0], 10.0, [0], theta=math.pi, speed=3.0)
    pursuers += ring([50.0, 50.0], 10.0, [120], theta=math.radians(300), speed=3.0)
    pursuers += ring([50.0, 50.0], 3.5, [240], theta=math.radians(240), speed=3.0)
    pursuers += [far_row(0), far_row(1)]
    obstacle = ring([50.0, 50.0], 6.5, [240])[0][:2] + [1.05]
    scenario = initial_scenario(pursuers=pursuers, evaders=[[50.0, 50.0, 0.0, 0.0], [100.0, 10.0, 0.0, 0.0]],
                                obstacles=[obstacle], evader_slots=4)
    world = World(scenario, evader_policy=ConstantEvader(EVADER_STILL))
    world.reset()
    return world


LATE_ACTIONS = np.array([[PURSUER_IDLE, PURSUER_IDLE, PURSUER_AHEAD, PURSUER_IDLE, PURSUER_IDLE]])


def test_crashed_pursuer_closes_a_ring_with_two_live_pursuers_later():
    world = late_ring_world()
    _, first = world.step(LATE_ACTIONS)
    assert first.collided[0].tolist() == [False, False, True, False, False]
    assert not first.captured.any()
    _, second = world.step(LATE_ACTIONS)
    assert second.captured[0].tolist() == [True, False]
    assert second.pursuer_target[0].tolist() == [-1, -1, 0, -1, -1]
    # the capturer is gone: nobody is paid the completion reward
    assert np.all(second.reward_terms[0, :, REWARD_TERMS.index("completion")] == 0.0)


def test_crashed_pursuer_tests_only_with_teammates_it_saw_when_it_crashed():
    world = late_ring_world()
    world.step(LATE_ACTIONS)
    world.state.pursuer_last_seen[0, 2, 1] = False  # as if p1 had been out of its view then
    _, second = world.step(LATE_ACTIONS)
    assert not second.captured.any()


# ---------------------------------------------------------------- section 9: the `published` reward
ARENA = (100.0, 100.0)


def published(state, collided=None, obstacle_before=None) -> dict[str, np.ndarray]:
    """`published` terms of env 0 by name -> [N]; recipients are the pursuers active in `state`
    plus the collided ones; obstacle distances before the move default to those of `state`."""
    n = state.pursuer_active.shape[1]
    collided = np.zeros((1, n), bool) if collided is None else np.array([collided], bool)
    recipients = state.pursuer_active | collided
    geometry = geometry_of(state)
    if obstacle_before is None:
        obstacle_before = first_perceived_obstacle_distance(geometry, state.obstacle_r, DEFAULT)
    remember_perceived(state, geometry, DEFAULT, recipients)
    ring_ = encircle(state, geometry, DEFAULT, recipients)
    out, team = published_reward_terms(state.pursuer_xy, recipients, collided, obstacle_before, geometry, ring_,
                                       DEFAULT, ARENA)
    return {**{name: out[0, :, i] for i, name in enumerate(REWARD_TERMS)}, "team": float(team[0])}


def test_reward_variant_is_chosen_by_name_in_the_scenario():
    assert Scenario(name="x").reward == "paper"
    assert Scenario(name="x", reward="published").to_dict()["reward"] == "published"
    with pytest.raises(ScenarioError, match="reward: must be one of 'paper', 'published'"):
        Scenario(name="x", reward="shaped")


def test_published_time_collision_and_boundary_are_the_papers():
    state = make_state([[20.0, 20.0, 0.0, 0.0], [-0.1, 50.0, 0.0, 0.0], [80.0, 20.0, 0.0, 0.0]], [[50.0, 90.0, 0, 0]],
                       pursuer_active=[True, True, False])
    got = published(state, collided=[False, False, True])
    assert got["time"].tolist() == [-1.0, -1.0, -1.0]
    assert got["collision"].tolist() == [0.0, 0.0, -80.0]
    assert got["boundary"].tolist() == [0.0, -5.0, 0.0]


def test_published_guidance_pays_every_evader_by_the_nearest_distance():
    # 10 m from E0, 30 m from E1 (encircled): 2 x 5 exp(-0.05 (10 - 8)) = 9.048
    state = make_state([[20.0, 20.0, 0.0, 0.0]], [[30.0, 20.0, 0, 0], [20.0, 50.0, 0, 0]], evader_active=[True, False])
    assert published(state)["guidance"][0] == pytest.approx(10 * math.exp(-0.1))


def test_published_guidance_beyond_d_encircle_grows_when_the_nearest_evader_is_closer():
    # 6 m from E0 (+5), 30 m from E1: 5 exp(-0.05 (6 - 8)) = 5.526 for E1
    state = make_state([[20.0, 20.0, 0.0, 0.0]], [[26.0, 20.0, 0, 0], [20.0, 50.0, 0, 0]])
    assert published(state)["guidance"][0] == pytest.approx(5 + 5 * math.exp(0.1))


@pytest.mark.parametrize("count, each", [(2, 0.0), (3, 5.0), (4, 3.5), (5, 2.0 - 10.0), (6, 0.5 - 10.0)])
def test_published_cooperation_by_pursuers_within_18_m(count, each):
    # P pursuers 15 m around E; one pursuer far away gets only the crowding penalty (P >= 5)
    pursuers = ring([50.0, 50.0], 15.0, [60 * k for k in range(count)]) + [[5.0, 5.0, 0, 0]]
    got = published(make_state(pursuers, [[50.0, 50.0, 0, 0]]))
    assert got["cooperation"][:count] == pytest.approx([each] * count)
    assert got["cooperation"][count] == pytest.approx(-10.0 if count >= 5 else 0.0)
    assert got["team"] == (-10.0 if count >= 5 else 0.0)  # the share every pursuer gets alike


def test_published_cooperation_counts_collided_pursuers_and_encircled_evaders():
    # three pursuers around an encircled evader, one of them collided earlier: the other two get 5
    pursuers = ring([50.0, 50.0], 15.0, [0, 120, 240])
    state = make_state(pursuers, [[50.0, 50.0, 0, 0], [5.0, 95.0, 0, 0]], pursuer_active=[True, True, False],
                       evader_active=[False, True])
    assert published(state)["cooperation"].tolist() == [5.0, 5.0, 0.0]


def test_published_emergency_sees_collided_pursuers_and_encircled_evaders():
    state = make_state([[20.0, 20.0, 0, 0], [23.0, 20.0, 0, 0], [60.0, 60.0, 0, 0]],
                       [[60.0, 63.0, 0, 0], [90.0, 90.0, 0, 0]], pursuer_active=[True, False, True],
                       evader_active=[False, True])
    assert published(state)["emergency"].tolist() == [-5.0, 0.0, -5.0]


def test_published_emergency_reads_the_first_perceived_obstacle_before_the_move():
    # obstacles 0 (15 m) and 1 (3 m) are both perceived: the published test reads obstacle 0 only
    state = make_state([[20.0, 20.0, 0, 0]], [[90.0, 90.0, 0, 0]], obstacles=[[35.0, 20.0, 1.0], [23.0, 20.0, 1.0]])
    geometry = geometry_of(state)
    before = first_perceived_obstacle_distance(geometry, state.obstacle_r, DEFAULT)
    assert before.tolist() == [[15.0]]
    assert published(state)["emergency"].tolist() == [0.0]
    assert published(state, obstacle_before=np.array([[3.5]]))["emergency"].tolist() == [-5.0]


def test_first_perceived_obstacle_is_inf_when_none_is_perceived():
    state = make_state([[20.0, 20.0, 0, 0]], [[90.0, 90.0, 0, 0]], obstacles=[[60.0, 20.0, 1.0]])
    assert first_perceived_obstacle_distance(geometry_of(state), state.obstacle_r, DEFAULT).tolist() == [[math.inf]]


def test_published_completion_divides_by_the_helpers():
    # even ring of three at 6 m: gaps all 2pi/3, std 0: 120 * (2 pi / 2) = 376.99
    state = make_state(ring([50.0, 50.0], 6.0, [0, 120, 240]), [[50.0, 50.0, 0, 0]])
    assert published(state)["completion"] == pytest.approx([120 * math.pi] * 3)


def test_published_completion_is_not_paid_in_the_step_the_pursuer_collides():
    state = make_state(ring([50.0, 50.0], 6.0, [0, 120, 240]), [[50.0, 50.0, 0, 0]], pursuer_active=[True, True, False])
    got = published(state, collided=[False, False, True])
    assert got["completion"] == pytest.approx([120 * math.pi, 120 * math.pi, 0.0])
    assert got["collision"].tolist() == [0.0, 0.0, -80.0]


def test_world_pays_the_published_reward_when_the_scenario_names_it():
    world_paper = crash_world()
    scenario = world_paper.scenario.replace(reward="published")
    world = World(scenario, evader_policy=ConstantEvader(EVADER_STILL))
    world.reset()
    _, paper = world_paper.step(ACTIONS)
    _, result = world.step(ACTIONS)
    completion = REWARD_TERMS.index("completion")
    # the even ring of p0, p1, p2 (the colliding p2 is not paid): 120 (2 pi / 3) vs 120 (2 pi / 2)
    assert paper.reward_terms[0, :2, completion] == pytest.approx([80 * math.pi] * 2, rel=1e-3)
    assert result.reward_terms[0, :2, completion] == pytest.approx([120 * math.pi] * 2, rel=1e-3)
