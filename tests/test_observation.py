"""Pursuer perception and observation (world.md section 5)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sim_helpers import (
    DEFAULT,
    PURSUER_IDLE,
    ROBOT_R,
    far_row,
    geometry_of,
    initial_scenario,
    make_state,
    random_state,
    to_ego,
    wrap_0_2pi,
)

from terl_rt.sim.evader import ConstantEvader
from terl_rt.sim.observation import ENTITY_TYPES, pursuer_observations, pursuit_status
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.simulator import Simulator
from terl_rt.sim.world import World

R = DEFAULT.perception_radius  # 20 m
P_SLOTS, O_SLOTS = 5, 5
# token columns
PX, PY, VX, VY, D, BEARING, LAST = range(7)  # LAST: pursuit_status (teammate) or heading (evader)
OBS_R, OBS_D, OBS_BEARING = 2, 3, 4


def observe(state, evader_slots: int = 8, params=DEFAULT):
    """Observations of `state` as the world returns them after a move (pursuit status refreshed)."""
    geometry = geometry_of(state)
    state.pursuer_pursuing = pursuit_status(geometry, params.related_distance)
    return pursuer_observations(state, geometry, params, evader_slots)


def lonely_evader():
    """One evader far away (every world needs one)."""
    return [[500.0, 500.0, 0.0, 0.0]]


def teammate_mask(obs, i: int = 0) -> np.ndarray:
    return obs.mask[0, i, 1:1 + P_SLOTS]


def evader_mask(obs, evader_slots: int, i: int = 0) -> np.ndarray:
    return obs.mask[0, i, 1 + P_SLOTS:1 + P_SLOTS + evader_slots]


def obstacle_mask(obs, evader_slots: int, i: int = 0) -> np.ndarray:
    return obs.mask[0, i, 1 + P_SLOTS + evader_slots:]


# ---------------------------------------------------------------- frames
def test_ego_token_holds_own_velocity_in_own_frame():
    # theta = pi/2: Rot^T (1, 2) = (cos*1 + sin*2, -sin*1 + cos*2) = (2, -1).
    state = make_state([[10.0, 10.0, math.pi / 2, 0.0]], lonely_evader(), pursuer_vel=[[1.0, 2.0]])
    obs = observe(state)
    assert obs.ego[0, 0, :2] == pytest.approx([2.0, -1.0], abs=1e-6)


def test_teammate_position_is_in_observer_frame():
    # Observer at (10, 10) facing +y (theta = pi/2). Teammate A at (10, 15): world offset (0, 5) ->
    # ego (5, 0), straight ahead. Teammate B at (13, 10): offset (3, 0) -> ego (0, -3), to the right.
    state = make_state(
        [[10.0, 10.0, math.pi / 2, 0.0], [10.0, 15.0, 0.0, 0.0], [13.0, 10.0, 0.0, 0.0]], lonely_evader()
    )
    tokens = observe(state).teammates[0, 0]
    # nearest first: B (3 m), then A (5 m)
    assert tokens[0, [PX, PY, D, BEARING]] == pytest.approx([0.0, -3.0, 3.0, -math.pi / 2], abs=1e-6)
    assert tokens[1, [PX, PY, D, BEARING]] == pytest.approx([5.0, 0.0, 5.0, 0.0], abs=1e-6)


def test_teammate_velocity_is_rotated_into_observer_frame():
    # observer theta = pi/2; teammate world velocity (1, 0) -> ego (0, -1)
    state = make_state(
        [[10.0, 10.0, math.pi / 2, 0.0], [10.0, 15.0, 0.0, 1.0]], lonely_evader(),
        pursuer_vel=[[0.0, 0.0], [1.0, 0.0]],
    )
    assert observe(state).teammates[0, 0, 0, [VX, VY]] == pytest.approx([0.0, -1.0], abs=1e-6)


def test_evader_token_features_for_known_heading():
    # Observer at origin, theta = pi/2. Evader at (0, 10), world velocity (0, -2) (coming closer):
    # p = Rot^T (0, 10) = (10, 0); v = Rot^T (0, -2) = (-2, 0); d = 10; bearing 0; heading atan2(0, -2) = pi.
    state = make_state([[0.0, 0.0, math.pi / 2, 0.0]], [[0.0, 10.0, 0.0, 0.0]], evader_vel=[[0.0, -2.0]])
    token = observe(state).evaders[0, 0, 0]
    assert token == pytest.approx([10.0, 0.0, -2.0, 0.0, 10.0, 0.0, math.pi], abs=1e-6)


def test_evader_heading_is_mapped_to_0_2pi():
    # observer theta = 0; evader velocity (0, -1) -> atan2 = -pi/2 -> heading 3pi/2
    state = make_state([[0.0, 0.0, 0.0, 0.0]], [[0.0, 10.0, 0.0, 0.0]], evader_vel=[[0.0, -1.0]])
    assert observe(state).evaders[0, 0, 0, LAST] == pytest.approx(3 * math.pi / 2, abs=1e-6)


def test_obstacle_token_features_for_known_heading():
    # Observer at origin, theta = pi/2; obstacle at (-6, 0), r = 1.05:
    # p = Rot^T (-6, 0) = (0, 6), to the left; [px, py, r, d, bearing] = [0, 6, 1.05, 6, pi/2].
    state = make_state([[0.0, 0.0, math.pi / 2, 0.0]], lonely_evader(), [[-6.0, 0.0, 1.05]])
    token = observe(state).obstacles[0, 0, 0]
    assert token == pytest.approx([0.0, 6.0, 1.05, 6.0, math.pi / 2], abs=1e-6)


def test_bearing_of_entity_straight_behind_is_plus_pi():
    # facing -x (theta = pi), a teammate at (5, 0) is straight behind: ego (-5, ~0);
    # bearing must be +pi (range (-pi, pi]), never -pi.
    state = make_state([[0.0, 0.0, math.pi, 0.0], [5.0, 0.0, 0.0, 0.0]], lonely_evader())
    bearing = observe(state).teammates[0, 0, 0, BEARING]
    assert bearing == pytest.approx(math.pi, abs=1e-6)
    assert bearing > 0


def test_bearing_behind_with_heading_zero_is_plus_pi():
    state = make_state([[0.0, 0.0, 0.0, 0.0], [-5.0, 0.0, 0.0, 0.0]], lonely_evader())
    assert observe(state).teammates[0, 0, 0, BEARING] == pytest.approx(math.pi, abs=1e-6)


# ---------------------------------------------------------------- slots and masks
def test_teammate_slots_are_filled_nearest_first():
    state = make_state(
        [[0.0, 0.0, 0.0, 0.0], [9.0, 0.0, 0.0, 0.0], [0.0, 3.0, 0.0, 0.0], [-6.0, 0.0, 0.0, 0.0]], lonely_evader()
    )
    assert observe(state).teammates[0, 0, :3, D] == pytest.approx([3.0, 6.0, 9.0], abs=1e-6)


def test_only_the_five_nearest_teammates_are_kept():
    # teammates at 8, 2, 7, 3, 6, 4, 5 m -> slots 2, 3, 4, 5, 6
    distances = [8.0, 2.0, 7.0, 3.0, 6.0, 4.0, 5.0]
    state = make_state([[0.0, 0.0, 0.0, 0.0]] + [[0.0, d, 0.0, 0.0] for d in distances], lonely_evader())
    obs = observe(state)
    assert obs.teammates[0, 0, :, D] == pytest.approx([2.0, 3.0, 4.0, 5.0, 6.0], abs=1e-6)
    assert teammate_mask(obs).all()


def test_empty_slots_are_zeros_with_mask_false():
    state = make_state([[0.0, 0.0, 0.0, 0.0], [3.0, 0.0, 0.0, 1.0], [0.0, 4.0, 0.0, 1.0]], lonely_evader())
    obs = observe(state)
    assert teammate_mask(obs).tolist() == [True, True, False, False, False]
    assert np.all(obs.teammates[0, 0, 2:] == 0.0)
    assert not obstacle_mask(obs, 8).any()
    assert np.all(obs.obstacles[0, 0] == 0.0)


def test_self_is_never_a_teammate():
    state = make_state([[0.0, 0.0, 0.0, 0.0], [100.0, 0.0, 0.0, 0.0]], lonely_evader())
    assert not teammate_mask(observe(state)).any()


def test_mask_layout_has_ego_teammates_evaders_obstacles():
    # length 1 + 5 + E + 5; ego always true
    state = make_state([[0.0, 0.0, 0.0, 0.0], [3.0, 0.0, 0.0, 0.0]], [[5.0, 5.0, 0.0, 0.0]], [[0.0, 6.0, 1.0]])
    obs = observe(state, evader_slots=4)
    assert obs.mask.shape == (1, 2, 1 + 5 + 4 + 5)
    assert obs.mask[0, 0].tolist() == [True] + [True, False, False, False, False] + [True, False, False, False] + [
        True, False, False, False, False]


def test_ego_mask_is_true_even_with_nothing_around():
    # alone: no teammate, no obstacle; the (far) evader is the only other token
    obs = observe(make_state([[0.0, 0.0, 0.0, 0.0]], lonely_evader()))
    assert obs.mask[0, 0].tolist() == [True] + [False] * 5 + [True] + [False] * 7 + [False] * 5


def test_entity_type_ids_follow_mask_order():
    assert ENTITY_TYPES == {"ego": 0, "teammate": 1, "evader": 2, "obstacle": 3}


# ---------------------------------------------------------------- perception
def test_teammate_exactly_at_R_plus_radius_is_perceived():
    reach = DEFAULT.perception_radius + ROBOT_R
    state = make_state([[0.0, 0.0, 0.0, 0.0], [reach, 0.0, 0.0, 0.0]], lonely_evader())
    obs = observe(state)
    assert teammate_mask(obs)[0]
    assert obs.teammates[0, 0, 0, D] == pytest.approx(reach, abs=1e-5)


def test_teammate_just_beyond_R_plus_radius_is_not_perceived():
    beyond = np.nextafter(DEFAULT.perception_radius + ROBOT_R, np.inf)
    state = make_state([[0.0, 0.0, 0.0, 0.0], [beyond, 0.0, 0.0, 0.0]], lonely_evader())
    assert not teammate_mask(observe(state)).any()


def test_obstacle_exactly_at_R_plus_its_radius_is_perceived():
    # r = 1.0: perceived up to 21.0 m
    state = make_state([[0.0, 0.0, 0.0, 0.0]], lonely_evader(), [[21.0, 0.0, 1.0]])
    assert obstacle_mask(observe(state), 8)[0]


def test_obstacle_just_beyond_R_plus_its_radius_is_not_perceived():
    state = make_state([[0.0, 0.0, 0.0, 0.0]], lonely_evader(), [[21.0 + 1e-9, 0.0, 1.0]])
    assert not obstacle_mask(observe(state), 8).any()


def test_collided_pursuer_is_not_perceived():
    state = make_state(
        [[0.0, 0.0, 0.0, 0.0], [3.0, 0.0, 0.0, 0.0], [6.0, 0.0, 0.0, 0.0]], lonely_evader(),
        pursuer_active=[True, False, True],
    )
    obs = observe(state)
    assert teammate_mask(obs).tolist() == [True, False, False, False, False]
    assert obs.teammates[0, 0, 0, D] == pytest.approx(6.0)


def test_encircled_evader_is_not_perceived():
    state = make_state([[0.0, 0.0, 0.0, 0.0]], [[5.0, 0.0, 0.0, 0.0], [9.0, 0.0, 0.0, 0.0]],
                       evader_active=[False, True])
    obs = observe(state)
    assert evader_mask(obs, 8).tolist() == [True] + [False] * 7
    assert obs.evaders[0, 0, 0, D] == pytest.approx(9.0)


def test_evader_is_seen_at_any_distance():
    state = make_state([[0.0, 0.0, 0.0, 0.0]], [[300.0, 400.0, 0.0, 0.0]])
    obs = observe(state)
    assert evader_mask(obs, 8)[0]
    assert obs.evaders[0, 0, 0, D] == pytest.approx(500.0)


def test_evader_slots_beyond_the_evader_count_are_empty():
    # M = 2 evaders, E = 8 slots
    state = make_state([[0.0, 0.0, 0.0, 0.0]], [[40.0, 0.0, 0.0, 0.0], [0.0, 30.0, 0.0, 0.0]])
    obs = observe(state, evader_slots=8)
    assert obs.evaders.shape == (1, 1, 8, 7)
    assert evader_mask(obs, 8).tolist() == [True, True] + [False] * 6
    assert obs.evaders[0, 0, :2, D] == pytest.approx([30.0, 40.0])
    assert np.all(obs.evaders[0, 0, 2:] == 0.0)


def test_evader_slots_keep_the_E_nearest():
    # M = 4 evaders at 50, 10, 30, 20 m; E = 2 -> 10, 20
    evaders = [[50.0, 0.0, 0.0, 0.0], [10.0, 0.0, 0.0, 0.0], [30.0, 0.0, 0.0, 0.0], [20.0, 0.0, 0.0, 0.0]]
    obs = observe(make_state([[0.0, 0.0, 0.0, 0.0]], evaders), evader_slots=2)
    assert obs.evaders.shape == (1, 1, 2, 7)
    assert obs.evaders[0, 0, :, D] == pytest.approx([10.0, 20.0])


def test_only_the_five_nearest_obstacles_are_kept():
    obstacles = [[0.0, d, 1.0] for d in (9.0, 3.0, 8.0, 4.0, 7.0, 5.0, 6.0)]
    obs = observe(make_state([[0.0, 0.0, 0.0, 0.0]], lonely_evader(), obstacles))
    assert obs.obstacles[0, 0, :, OBS_D] == pytest.approx([3.0, 4.0, 5.0, 6.0, 7.0])


# ---------------------------------------------------------------- ego features
def test_d_nearest_is_centre_distance_to_nearest_obstacle():
    obs = observe(make_state([[0.0, 0.0, 0.0, 0.0]], lonely_evader(), [[15.0, 0.0, 1.0], [0.0, 12.0, 1.0]]))
    assert obs.ego[0, 0, 2] == pytest.approx(12.0)


def test_d_nearest_is_capped_at_R():
    # obstacle at 20.5 m with r = 1.0 is perceived (<= 21) but not within R = 20: d_nearest = R
    obs = observe(make_state([[0.0, 0.0, 0.0, 0.0]], lonely_evader(), [[20.5, 0.0, 1.0]]))
    assert obstacle_mask(obs, 8)[0]
    assert obs.obstacles[0, 0, 0, OBS_D] == pytest.approx(20.5)
    assert obs.ego[0, 0, 2] == pytest.approx(R)


def test_d_nearest_is_R_without_obstacles():
    assert observe(make_state([[0.0, 0.0, 0.0, 0.0]], lonely_evader())).ego[0, 0, 2] == pytest.approx(R)


def test_pursuit_status_is_one_at_exactly_related_distance():
    # "within related_distance = 18" is inclusive, like "within d_encircle" in section 7
    obs = observe(make_state([[0.0, 0.0, 0.0, 0.0]], [[18.0, 0.0, 0.0, 0.0]]))
    assert obs.ego[0, 0, 3] == 1.0


def test_pursuit_status_is_zero_beyond_related_distance():
    obs = observe(make_state([[0.0, 0.0, 0.0, 0.0]], [[18.01, 0.0, 0.0, 0.0]]))
    assert obs.ego[0, 0, 3] == 0.0


def test_pursuit_status_counts_encircled_evaders_like_the_published_simulator():
    # its update_pursuing_status takes the nearest of every evader, encircled ones included
    state = make_state([[0.0, 0.0, 0.0, 0.0]], [[5.0, 0.0, 0.0, 0.0], [50.0, 0.0, 0.0, 0.0]],
                       evader_active=[False, True])
    assert observe(state).ego[0, 0, 3] == 1.0


def test_teammate_token_carries_the_teammates_pursuit_status():
    # observer 30 m from the evader (status 0); teammate 15 m from it (status 1)
    state = make_state([[0.0, 0.0, 0.0, 0.0], [15.0, 0.0, 0.0, 0.0]], [[30.0, 0.0, 0.0, 0.0]])
    obs = observe(state)
    assert obs.ego[0, 0, 3] == 0.0
    assert obs.teammates[0, 0, 0, LAST] == 1.0
    assert obs.ego[0, 1, 3] == 1.0


def status_world(evader_heading: float):
    # An evader 17.5 m ahead of pursuer 0, driving at 3.5 m/s (a = 0.4 balances drag) with the
    # given heading: 1.75 m a step.
    scenario = initial_scenario(
        pursuers=[[50.0, 50.0, 0.0, 0.0], far_row(0), far_row(1)],
        evaders=[[67.5, 50.0, evader_heading, 3.5]],
    )
    return World(scenario, evader_policy=ConstantEvader(12))  # 12 = (a index 2, w index 2) = (0.4, 0)


def test_pursuit_status_is_zero_after_reset():
    # the published pursuers start with is_pursuing unset; it is first computed in step 1
    assert status_world(0.0).reset().ego[0, 0, 3] == 0.0


def test_pursuit_status_is_refreshed_after_the_evaders_move():
    world = status_world(math.pi)  # towards the pursuer: 17.5 -> 15.75 m
    world.reset()
    obs, _ = world.step(np.full((1, 3), PURSUER_IDLE))
    assert obs.ego[0, 0, 3] == 1.0
    world = status_world(0.0)  # away: 17.5 -> 19.25 m
    world.reset()
    obs, _ = world.step(np.full((1, 3), PURSUER_IDLE))
    assert world.state.evader_xy[0, 0, 0] > 68.0
    assert obs.ego[0, 0, 3] == 0.0


# ---------------------------------------------------------------- shapes and dtypes
def test_world_observations_have_batch_shapes_and_dtypes():
    scenario = Scenario.preset("small-11")
    obs = World(scenario, num_envs=2, seed=1).reset()
    assert obs.ego.shape == (2, 11, 4)
    assert obs.teammates.shape == (2, 11, 5, 7)
    assert obs.evaders.shape == (2, 11, 8, 7)
    assert obs.obstacles.shape == (2, 11, 5, 5)
    assert obs.mask.shape == (2, 11, 1 + 5 + 8 + 5)
    for name in ("ego", "teammates", "evaders", "obstacles"):
        assert getattr(obs, name).dtype == np.float32, name
    assert obs.mask.dtype == np.bool_
    assert set(obs.as_inputs()) == {"ego", "teammates", "evaders", "obstacles", "mask"}


def test_simulator_observation_has_one_row_per_active_pursuer():
    # pursuers 0 and 1 drive head-on from 2.5 m (2r = 2.236 m): both collide in the first step
    scenario = initial_scenario(
        pursuers=[[30.0, 30.0, 0.0, 2.0], [32.5, 30.0, math.pi, 2.0], far_row(0), far_row(1), far_row(2)],
        evaders=[[80.0, 30.0, 0.0, 0.0]],
        evader_slots=3,
    )
    sim = Simulator(scenario, evader_policy=ConstantEvader(7))
    obs = sim.reset()
    assert obs.ego.shape == (5, 4)
    obs, info = sim.step(np.full(5, PURSUER_IDLE))
    assert info.collided.tolist() == [True, True, False, False, False]
    assert obs.pursuer_index.tolist() == [2, 3, 4]
    assert obs.ego.shape == (3, 4)
    assert obs.teammates.shape == (3, 5, 7)
    assert obs.evaders.shape == (3, 3, 7)
    assert obs.obstacles.shape == (3, 5, 5)
    assert obs.mask.shape == (3, 1 + 5 + 3 + 5)
    assert obs.ego.dtype == np.float32 and obs.mask.dtype == np.bool_


# ---------------------------------------------------------------- against a plain loop
def reference_observation(state, b: int, i: int, params, evader_slots: int) -> dict[str, np.ndarray]:
    """Observation of pursuer i of env b, written straight from world.md section 5."""
    radius, reach = params.perception_radius, params.perception_radius + params.robot_radius
    own, theta = state.pursuer_xy[b, i], state.pursuer_theta[b, i]

    def bearing(v):
        angle = math.atan2(v[1], v[0])
        return math.pi if angle == -math.pi else angle

    def status(k):  # the nearest of every evader, encircled ones included
        dists = [np.hypot(*(state.pursuer_xy[b, k] - e)) for e in state.evader_xy[b]]
        return 1.0 if dists and min(dists) <= params.related_distance else 0.0

    obstacle_d = [float(np.hypot(*(o - own))) for o in state.obstacle_xy[b]]
    d_nearest = min([d for d in obstacle_d if d <= radius], default=radius)
    ego = np.array([*to_ego(theta, state.pursuer_vel[b, i]), d_nearest, status(i)])

    teammates, evaders, obstacles = np.zeros((5, 7)), np.zeros((evader_slots, 7)), np.zeros((5, 5))
    masks = [np.zeros(5, bool), np.zeros(evader_slots, bool), np.zeros(5, bool)]
    seen = sorted(
        (float(np.hypot(*(state.pursuer_xy[b, k] - own))), k)
        for k in range(state.pursuer_xy.shape[1])
        if k != i and state.pursuer_active[b, k] and np.hypot(*(state.pursuer_xy[b, k] - own)) <= reach
    )[:5]
    for slot, (d, k) in enumerate(seen):
        p, v = to_ego(theta, state.pursuer_xy[b, k] - own), to_ego(theta, state.pursuer_vel[b, k])
        teammates[slot] = [p[0], p[1], v[0], v[1], d, bearing(p), status(k)]
        masks[0][slot] = True
    seen = sorted(
        (float(np.hypot(*(state.evader_xy[b, j] - own))), j)
        for j in range(state.evader_xy.shape[1]) if state.evader_active[b, j]
    )[:evader_slots]
    for slot, (d, j) in enumerate(seen):
        p, v = to_ego(theta, state.evader_xy[b, j] - own), to_ego(theta, state.evader_vel[b, j])
        evaders[slot] = [p[0], p[1], v[0], v[1], d, bearing(p), wrap_0_2pi(math.atan2(v[1], v[0]))]
        masks[1][slot] = True
    seen = sorted((d, k) for k, d in enumerate(obstacle_d) if d <= radius + state.obstacle_r[b, k])[:5]
    for slot, (d, k) in enumerate(seen):
        p = to_ego(theta, state.obstacle_xy[b, k] - own)
        obstacles[slot] = [p[0], p[1], state.obstacle_r[b, k], d, bearing(p)]
        masks[2][slot] = True
    mask = np.concatenate([[True], *masks])
    return {"ego": ego, "teammates": teammates, "evaders": evaders, "obstacles": obstacles, "mask": mask}


@pytest.mark.parametrize("evader_slots", [3, 8])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_observations_match_plain_loop_on_random_worlds(seed, evader_slots):
    rng = np.random.default_rng(seed)
    state = random_state(rng, num_envs=3, num_pursuers=9, num_evaders=5, num_obstacles=7, low=0.0, high=45.0)
    obs = observe(state, evader_slots=evader_slots)
    compared = 0
    for b in range(3):
        for i in range(9):
            if not state.pursuer_active[b, i]:
                continue  # collided pursuers' rows carry no meaning
            expected = reference_observation(state, b, i, DEFAULT, evader_slots)
            for group in ("ego", "teammates", "evaders", "obstacles"):
                np.testing.assert_allclose(getattr(obs, group)[b, i], expected[group], rtol=1e-5, atol=1e-4,
                                           err_msg=f"{group} of env {b} pursuer {i}")
            np.testing.assert_array_equal(obs.mask[b, i], expected["mask"], err_msg=f"mask of env {b} pursuer {i}")
            compared += 1
    assert compared > 10
