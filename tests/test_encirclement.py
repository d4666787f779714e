"""Collisions (world.md section 6) and the encirclement test (section 7)."""

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
    ring,
    stack_states,
)

from terl_rt.sim.collisions import TOUCHED_EVADER, TOUCHED_OBSTACLE, TOUCHED_TEAMMATE, collisions
from terl_rt.sim.encirclement import encircle, remember_perceived
from terl_rt.sim.evader import ConstantEvader
from terl_rt.sim.params import WorldParams
from terl_rt.sim.world import World

EVADER = [50.0, 50.0, 0.0, 0.0]


def ring_around(bearings_deg, radius: float = 6.0, **kwargs):
    """Pursuers at `radius` m around the evader at (50, 50), at the given bearings."""
    return make_state(ring(EVADER[:2], radius, bearings_deg), [EVADER], **kwargs)


def run_encircle(state, params=DEFAULT):
    """The world's test with every active pursuer present (nobody collides in this step)."""
    geometry = geometry_of(state)
    remember_perceived(state, geometry, params, state.pursuer_active)
    return encircle(state, geometry, params, state.pursuer_active)


def run_collisions(state):
    return collisions(state, geometry_of(state), DEFAULT)[0][0].tolist()


# ---------------------------------------------------------------- collisions
def test_pursuers_touching_exactly_both_collide():
    # centre distance r + r = 2r: distance minus both radii = 0 <= 0
    state = make_state([[-ROBOT_R, 0.0, 0.0, 0.0], [ROBOT_R, 0.0, 0.0, 0.0], [40.0, 0.0, 0.0, 0.0]],
                       [[80.0, 0.0, 0.0, 0.0]])
    assert run_collisions(state) == [True, True, False]


def test_pursuers_just_apart_do_not_collide():
    state = make_state([[0.0, 0.0, 0.0, 0.0], [np.nextafter(2 * ROBOT_R, np.inf), 0.0, 0.0, 0.0]],
                       [[80.0, 0.0, 0.0, 0.0]])
    assert run_collisions(state) == [False, False]


def test_pursuer_touching_an_evader_collides():
    state = make_state([[0.0, 0.0, 0.0, 0.0], [40.0, 0.0, 0.0, 0.0]], [[2 * ROBOT_R, 0.0, 0.0, 0.0]])
    assert run_collisions(state) == [True, False]


def test_pursuer_touching_an_obstacle_collides():
    # obstacle of radius 1.0 at r + 1.0: touching
    state = make_state([[0.0, 0.0, 0.0, 0.0], [40.0, 0.0, 0.0, 0.0]], [[80.0, 0.0, 0.0, 0.0]],
                       [[ROBOT_R + 1.0, 0.0, 1.0]])
    assert run_collisions(state) == [True, False]


def test_pursuer_near_but_clear_of_an_obstacle_does_not_collide():
    state = make_state([[0.0, 0.0, 0.0, 0.0]], [[80.0, 0.0, 0.0, 0.0]], [[ROBOT_R + 1.0 + 1e-9, 0.0, 1.0]])
    assert run_collisions(state) == [False]


def test_collided_pursuer_causes_no_collision():
    state = make_state([[0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]], [[80.0, 0.0, 0.0, 0.0]],
                       pursuer_active=[True, False])
    assert run_collisions(state) == [False, False]


def test_encircled_evader_causes_no_collision():
    state = make_state([[0.0, 0.0, 0.0, 0.0]], [[1.0, 0.0, 0.0, 0.0]], evader_active=[False])
    assert run_collisions(state) == [False]


def test_collision_is_checked_after_everyone_moved():
    # Two pursuers 4 m apart drive head-on at 3 m/s (a = 0.4 keeps s = 3): each covers 1.5 m,
    # so they end 1 m apart (< 2r = 2.236 m) and both collide.
    scenario = initial_scenario(
        pursuers=[[30.0, 30.0, 0.0, 3.0], [34.0, 30.0, math.pi, 3.0], far_row(0), far_row(1), far_row(2)],
        evaders=[[90.0, 60.0, 0.0, 0.0]],
    )
    world = World(scenario, evader_policy=ConstantEvader(7))
    world.reset()
    _, result = world.step(np.array([[7, 7, PURSUER_IDLE, PURSUER_IDLE, PURSUER_IDLE]]))  # 7 = (0.4, 0)
    assert result.collided[0].tolist() == [True, True, False, False, False]
    assert world.state.pursuer_active[0].tolist() == [False, False, True, True, True]


def test_a_collision_records_what_the_pursuers_disc_touched():
    # pursuer 0 touches pursuer 1 and the evader, pursuer 2 an obstacle, pursuer 3 nothing
    state = make_state([[0.0, 0.0, 0.0, 0.0], [-2 * ROBOT_R, 0.0, 0.0, 0.0], [40.0, 0.0, 0.0, 0.0], [70.0, 0.0, 0.0, 0.0]],
                       [[2 * ROBOT_R, 0.0, 0.0, 0.0]], [[40.0 + ROBOT_R + 1.0, 0.0, 1.0]])
    collided, touched = collisions(state, geometry_of(state), DEFAULT)
    assert collided[0].tolist() == [True, True, True, False]
    assert touched[0].tolist() == [TOUCHED_TEAMMATE | TOUCHED_EVADER, TOUCHED_TEAMMATE, TOUCHED_OBSTACLE, 0]


def test_an_episodes_metrics_count_collided_pursuers_by_what_they_touched():
    # pursuers 0 and 1 head-on (each touches a teammate); pursuer 2 drives into the evader
    scenario = initial_scenario(
        pursuers=[[30.0, 30.0, 0.0, 3.0], [34.0, 30.0, math.pi, 3.0], [60.0, 30.0, 0.0, 2.0], far_row(0), far_row(1),
                  far_row(2)],
        evaders=[[62.5, 30.0, math.pi, 2.0]],
    )
    world = World(scenario, evader_policy=ConstantEvader(7))
    world.reset()
    world.step(np.array([[7, 7, PURSUER_IDLE, PURSUER_IDLE, PURSUER_IDLE, PURSUER_IDLE]]))
    metrics = world.metrics()
    assert metrics.pursuers_collided == 3
    assert metrics.collisions_touched == {"teammate": 2, "evader": 1, "obstacle": 0}
    world.reset()  # a new episode records afresh
    assert world.metrics().collisions_touched == {"teammate": 0, "evader": 0, "obstacle": 0}


def test_evaders_are_never_deactivated_by_contact():
    # pursuer 0 and evader 0 drive head-on from 2.5 m; evader 1 runs into evader 0 from behind
    scenario = initial_scenario(
        pursuers=[[30.0, 30.0, 0.0, 2.0], far_row(0), far_row(1), far_row(2)],
        evaders=[[32.5, 30.0, math.pi, 2.0], [35.0, 30.0, math.pi, 3.5]],
    )
    world = World(scenario, evader_policy=ConstantEvader(7))
    world.reset()
    _, result = world.step(np.full((1, 4), PURSUER_IDLE))
    assert result.collided[0, 0]
    assert world.state.evader_active[0].tolist() == [True, True]


def test_collided_pursuer_stops_moving():
    scenario = initial_scenario(
        pursuers=[[30.0, 30.0, 0.0, 2.0], [32.5, 30.0, math.pi, 2.0], far_row(0), far_row(1), far_row(2)],
        evaders=[[90.0, 60.0, 0.0, 0.0]],
    )
    world = World(scenario, evader_policy=ConstantEvader(7))
    world.reset()
    world.step(np.full((1, 5), PURSUER_IDLE))
    frozen = world.state.pursuer_xy[0, :2].copy()
    world.step(np.full((1, 5), 7))
    assert np.array_equal(world.state.pursuer_xy[0, :2], frozen)
    assert np.all(world.state.pursuer_vel[0, :2] == 0.0)


# ---------------------------------------------------------------- encirclement: passing cases
def test_even_ring_of_three_captures_and_all_share_it():
    ring = run_encircle(ring_around([0, 120, 240]))
    assert ring.evader_captured.tolist() == [[True]]
    assert ring.pursuer_target.tolist() == [[0, 0, 0]]
    assert ring.ring_size.tolist() == [[3, 3, 3]]
    assert ring.gap_std[0] == pytest.approx([0.0, 0.0, 0.0], abs=1e-12)


def test_ring_gap_std_is_std_of_the_cyclic_gaps():
    # bearings 0, 100, 220 deg -> gaps 100, 120, 140 deg; (population) std = sqrt(800/3) deg = 0.285 rad
    ring = run_encircle(ring_around([0, 100, 220]))
    assert ring.evader_captured[0, 0]
    assert ring.gap_std[0, 0] == pytest.approx(math.radians(math.sqrt(800 / 3)), abs=1e-9)


def test_pursuer_beyond_d_encircle_is_not_in_the_ring():
    state = make_state(ring(EVADER[:2], 6.0, [0, 120, 240]) + ring(EVADER[:2], 8.5, [60]), [EVADER])
    ring_ = run_encircle(state)
    assert ring_.pursuer_target.tolist() == [[0, 0, 0, -1]]
    assert ring_.ring_size.tolist() == [[3, 3, 3, 0]]


# ---------------------------------------------------------------- criterion 1-2: distances and count
def test_one_helper_is_not_enough():
    ring_ = run_encircle(ring_around([0, 180]))
    assert not ring_.evader_captured.any()
    assert ring_.pursuer_target.tolist() == [[-1, -1]]


def strict_inclusive_state(p2_distance: float):
    # p0 at bearing 0 (6 m), p1 at 135 deg (6 m), p2 straight below at `p2_distance`:
    # gaps 135, 135, 90 deg pass psi and kappa.
    pursuers = ring(EVADER[:2], 6.0, [0, 135]) + [[50.0, 50.0 - p2_distance, 0.0, 0.0]]
    return make_state(pursuers, [EVADER])


def test_helper_exactly_at_d_encircle_does_not_count():
    # p2 is exactly 8 m away: not *strictly* within, so p0 and p1 have one helper each
    ring_ = run_encircle(strict_inclusive_state(8.0))
    assert ring_.pursuer_target[0, :2].tolist() == [-1, -1]


def test_pursuer_exactly_at_d_encircle_can_capture():
    # p2 itself at exactly 8 m passes criterion 1 (<= 8) with helpers p0, p1 strictly within
    ring_ = run_encircle(strict_inclusive_state(8.0))
    assert ring_.pursuer_target[0].tolist() == [-1, -1, 0]
    assert ring_.evader_captured.tolist() == [[True]]


def test_all_three_capture_once_p2_is_strictly_within():
    ring_ = run_encircle(strict_inclusive_state(7.9))
    assert ring_.pursuer_target[0].tolist() == [0, 0, 0]


def test_helper_not_perceived_does_not_count():
    # R = 5: perceived up to 5 + 1.118 = 6.118 m; ring mates of a 6 m ring are 6 sqrt(3) = 10.39 m apart
    params = WorldParams(perception_radius=5.0)
    assert not run_encircle(ring_around([0, 120, 240]), params).evader_captured.any()
    assert run_encircle(ring_around([0, 120, 240]), DEFAULT).evader_captured.all()


def test_collided_helper_does_not_count():
    state = ring_around([0, 120, 240], pursuer_active=[True, True, False])
    ring_ = run_encircle(state)
    assert not ring_.evader_captured.any()
    assert ring_.pursuer_target.tolist() == [[-1, -1, -1]]


def test_encircled_evader_is_not_encircled_again():
    state = ring_around([0, 120, 240], evader_active=[False])
    ring_ = run_encircle(state)
    assert not ring_.evader_captured.any()
    assert ring_.pursuer_target.tolist() == [[-1, -1, -1]]


# ---------------------------------------------------------------- criterion 3: gaps
def test_largest_gap_above_pi_fails():
    # bearings 0, 81, 162 deg: gaps 81, 81, 198; ratio 198/81 = 2.44 <= 3 but 198 > 180
    assert not run_encircle(ring_around([0, 81, 162])).evader_captured.any()


def test_largest_gap_just_below_pi_passes():
    # bearings 0, 91, 182 deg: gaps 91, 91, 178
    assert run_encircle(ring_around([0, 91, 182])).evader_captured.all()


def test_uneven_spacing_beyond_kappa_fails():
    # bearings 0, 27, 135, 243 deg: gaps 27, 108, 108, 117; max 117 <= 180 but 117 > 3 * 27 = 81
    assert not run_encircle(ring_around([0, 27, 135, 243])).evader_captured.any()


def test_uneven_spacing_within_kappa_passes():
    # bearings 0, 45, 144, 252 deg: gaps 45, 99, 108, 108; 108 <= 3 * 45 = 135
    assert run_encircle(ring_around([0, 45, 144, 252])).evader_captured.all()


def test_all_pursuers_on_one_side_fail():
    # bearings 0, 30, 60, 90 deg: gaps 30, 30, 30, 270
    assert not run_encircle(ring_around([0, 30, 60, 90])).evader_captured.any()


# ---------------------------------------------------------------- one capture per pursuer per step
def two_ring_state(swap: bool):
    """Evader A at (50, 50) ringed by p0, p1, p2 (4.5 m, 0/120/240 deg); evader B at (59.5, 50) ringed
    by p0 (bearing 180), p3 (290), p4 (70) at 5 m. With R = 7.5 (reach 8.618 m) p0 perceives p3 and p4
    (8.19 m away) but p3 and p4 (9.40 m apart) do not perceive each other: only p0 passes B."""
    a, b = [50.0, 50.0], [59.5, 50.0]
    pursuers = ring(a, 4.5, [0, 120, 240]) + ring(b, 5.0, [290, 70])
    evaders = [b + [0.0, 0.0], a + [0.0, 0.0]] if swap else [a + [0.0, 0.0], b + [0.0, 0.0]]
    return make_state(pursuers, evaders)


def test_pursuer_captures_only_the_first_evader_in_index_order():
    params = WorldParams(perception_radius=7.5)
    ring_ = run_encircle(two_ring_state(swap=False), params)
    # p0 passes both A (index 0) and B (index 1): it takes A; nobody else passes B
    assert ring_.pursuer_target.tolist() == [[0, 0, 0, -1, -1]]
    assert ring_.evader_captured.tolist() == [[True, False]]


def test_first_evader_in_index_order_decides_which_is_taken():
    params = WorldParams(perception_radius=7.5)
    ring_ = run_encircle(two_ring_state(swap=True), params)
    # now B has index 0: p0 takes B; p1 and p2 still take A (index 1) with p0 as a helper
    assert ring_.pursuer_target.tolist() == [[0, 1, 1, -1, -1]]
    assert ring_.evader_captured.tolist() == [[True, True]]


# ---------------------------------------------------------------- captured evaders in the world
def capture_world():
    # E0 at (50, 50) accelerates from rest (tiny drift) inside a ring p0/p1/p2 (6 m, 0/120/240 deg);
    # p3 starts 6 m to its left (bearing 180) driving at it at 3 m/s; E1 is far away.
    pursuers = ring(EVADER[:2], 6.0, [0, 120, 240]) + [[44.0, 50.0, 0.0, 3.0]]
    scenario = initial_scenario(pursuers=pursuers, evaders=[EVADER, [100.0, 100.0, 0.0, 0.0]], evader_slots=4)
    world = World(scenario, evader_policy=ConstantEvader(12))  # 12 = (0.4, 0)
    world.reset()
    return world


ACTIONS = np.array([[PURSUER_IDLE, PURSUER_IDLE, PURSUER_IDLE, 7]])  # p3: 7 = (0.4, 0)


def test_captured_evader_is_frozen_from_the_next_step():
    world = capture_world()
    _, result = world.step(ACTIONS)
    assert result.captured[0].tolist() == [True, False]
    assert result.pursuer_target[0].tolist() == [0, 0, 0, 0]
    frozen = world.state.evader_xy[0, 0].copy()
    e1 = world.state.evader_xy[0, 1].copy()
    world.step(ACTIONS)
    assert np.array_equal(world.state.evader_xy[0, 0], frozen)
    assert np.all(world.state.evader_vel[0, 0] == 0.0)
    assert world.state.evader_xy[0, 1, 0] > e1[0]  # the other evader still moves


def test_captured_evader_is_no_longer_perceived():
    world = capture_world()
    obs, _ = world.step(ACTIONS)
    evader_masks = obs.mask[0, :, 1 + 5:1 + 5 + 4]
    assert evader_masks.sum(-1).tolist() == [1, 1, 1, 1]
    # the one left is E1, about 70 m away
    assert np.all(obs.evaders[0, :, 0, 4] > 60.0)


def test_captured_evader_no_longer_collides():
    # p3 drives through E0's frozen position: 44 -> 45.5 -> 47 -> 48.5 m, ~1.5 m from E0 after step 3
    world = capture_world()
    for _ in range(3):
        _, result = world.step(ACTIONS)
        assert not result.collided.any()
    gap = np.hypot(*(world.state.pursuer_xy[0, 3] - world.state.evader_xy[0, 0]))
    assert gap < 2 * ROBOT_R
    assert world.state.pursuer_active[0, 3]


def test_pursuer_that_collides_in_the_step_still_helps_encircle():
    # Even ring p0/p1/p2 (6 m); p3 sits 2.5 m beyond p2, 8.5 m from the evader (no helper), and p2
    # drives out to it at 2 m/s, so p2 and p3 collide in this step. p2 still counts in this
    # step's test (world.md section 6).
    pursuers = ring(EVADER[:2], 6.0, [0, 120]) + ring(EVADER[:2], 6.0, [240], theta=math.radians(240), speed=2.0)
    pursuers += ring(EVADER[:2], 8.5, [240]) + [far_row(0), far_row(1)]
    scenario = initial_scenario(pursuers=pursuers, evaders=[EVADER, [100.0, 100.0, 0.0, 0.0]], evader_slots=4)
    world = World(scenario, evader_policy=ConstantEvader(7))
    world.reset()
    _, result = world.step(np.full((1, 6), PURSUER_IDLE))
    assert result.collided[0].tolist() == [False, False, True, True, False, False]
    assert result.captured[0].tolist() == [True, False]
    assert result.pursuer_target[0].tolist() == [0, 0, 0, -1, -1, -1]


# ---------------------------------------------------------------- against a plain loop
def reference_encircle(state, params):
    """(captured [B, M], target [B, N], ring size [B, N], gap std [B, N]) straight from section 7,
    every active pursuer present; collided ones test with state.pursuer_last_seen."""
    num_envs, n = state.pursuer_active.shape
    m = state.evader_active.shape[1]
    captured = np.zeros((num_envs, m), bool)
    target = np.full((num_envs, n), -1)
    size = np.zeros((num_envs, n), int)
    std = np.zeros((num_envs, n))
    reach = params.perception_radius + params.robot_radius
    last_seen = state.pursuer_last_seen.copy()
    for b in range(num_envs):
        pxy, exy = state.pursuer_xy[b], state.evader_xy[b]
        for p in range(n):
            for j in range(m):
                if not state.evader_active[b, j] or np.hypot(*(pxy[p] - exy[j])) > params.d_encircle:
                    continue
                # an active pursuer perceives now; a collided one what it perceived last
                helpers = [
                    q for q in range(n)
                    if q != p and state.pursuer_active[b, q]
                    and (np.hypot(*(pxy[q] - pxy[p])) <= reach if state.pursuer_active[b, p] else last_seen[b, p, q])
                    and np.hypot(*(pxy[q] - exy[j])) < params.d_encircle
                ]
                if len(helpers) < 2:
                    continue
                angles = sorted(math.atan2(*(pxy[q] - exy[j])[::-1]) % (2 * math.pi) for q in [p] + helpers)
                gaps = [angles[k + 1] - angles[k] for k in range(len(angles) - 1)]
                gaps.append(angles[0] + 2 * math.pi - angles[-1])
                if max(gaps) <= params.max_gap and max(gaps) <= params.gap_ratio * min(gaps):
                    captured[b, j] = True
                    target[b, p], size[b, p], std[b, p] = j, len(angles), np.std(gaps)
                    break
    return captured, target, size, std


def test_encirclement_matches_plain_loop_on_random_clustered_worlds():
    rng = np.random.default_rng(5)
    num_envs, n, m = 100, 10, 3
    states = []
    for _ in range(num_envs):
        evaders = rng.uniform(20, 40, (m, 2))
        home = evaders[rng.integers(0, m, n)]
        angle, dist = rng.uniform(0, 2 * np.pi, n), rng.uniform(2.0, 8.5, n)
        pursuers = home + dist[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
        states.append(make_state(
            [[x, y, 0.0, 0.0] for x, y in pursuers], [[x, y, 0.0, 0.0] for x, y in evaders],
            pursuer_active=rng.random(n) < 0.9, evader_active=rng.random(m) < 0.9,
        ))
    state = stack_states(states)
    state.pursuer_last_seen = rng.random((num_envs, n, n)) < 0.5  # collided pursuers' last perception

    captured, target, size, std = reference_encircle(state, DEFAULT)
    got = run_encircle(state)
    assert captured.sum() >= 8 and (target >= 0).sum() >= 25  # the worlds do exercise captures
    np.testing.assert_array_equal(got.evader_captured, captured)
    np.testing.assert_array_equal(got.pursuer_target, target)
    np.testing.assert_array_equal(got.ring_size, size)
    np.testing.assert_allclose(got.gap_std, std, atol=1e-9)
