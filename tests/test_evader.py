"""The published APF evader (world.md section 8), quirks included; the registry of evaders
and the others it names (docs/simulator.md, "Evaders").

Expected forces are worked out from the section 8 formulas in the comments; the action
index is i_a * 5 + i_w with a_set (-0.4, 0, 0.4), w_set (-pi/6, -pi/12, 0, pi/12, pi/6).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from sim_helpers import DEFAULT, geometry_of, initial_scenario, make_state, random_state, ring, to_ego

from terl_rt.sim.actions import EVADER_YAW_RATES
import terl_rt.sim.evader
from terl_rt.sim.evader import (
    DEFAULT_EVADER,
    EVADERS,
    ConstantEvader,
    PublishedAPFEvader,
    StillEvader,
    UnknownEvader,
    WidestGapEvader,
    build_evader,
    register_evader,
    widest_gap_bisector,
)
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.world import World

ARENA = (100.0, 100.0)
K_REP, D0 = 5000.0, 15.0
PARKED = [[90.0, 10.0, 0.0, 0.0]]  # a pursuer far from everything (every world has some)


def decide(evaders, pursuers=PARKED, obstacles=(), arena=ARENA, params=DEFAULT, **kwargs) -> list[int]:
    state = make_state(pursuers, evaders, obstacles, **kwargs)
    return PublishedAPFEvader().act(state, geometry_of(state), params, arena)[0].tolist()


def repulsion(d: float) -> float:
    """k_rep (1/d - 1/d0) / d^2 for a clearance d < d0."""
    return K_REP * (1.0 / d - 1.0 / D0) / d**2


def action(accel_index: int, yaw_index: int) -> int:
    return accel_index * 5 + yaw_index


# ---------------------------------------------------------------- free evader
def test_free_evader_below_v_min_speeds_up_straight():
    # F = 0: delta = 0 -> w = 0 (index 2); a_proj = 0 <= 0.1 and |v| = 0.5 < v_min -> +0.4 (index 2)
    assert decide([[50.0, 50.0, 0.0, 0.5]]) == [action(2, 2)]


def test_free_evader_above_v_min_keeps_its_speed():
    # |v| = 2 >= v_min -> a = 0 (index 1)
    assert decide([[50.0, 50.0, 0.0, 2.0]]) == [action(1, 2)]


def test_evader_at_rest_projects_on_unit_x():
    # At rest (|v| <= 1e-3) the velocity angle is 0 and the projection axis is ego x.
    # Facing +y, an obstacle at world (50, 46) is behind it: ego p = (-4, 0); d = 4 - 1 - 0.8 = 2.2;
    # F = 400.7 along -p/|p| = ego +x. delta = 0 -> index 2; a_proj = 400.7/500 = 0.80 > 0.1 -> brake.
    assert repulsion(2.2) == pytest.approx(400.7, abs=0.1)
    assert decide([[50.0, 50.0, math.pi / 2, 0.0]], obstacles=[[50.0, 46.0, 1.0]]) == [action(0, 2)]


# ---------------------------------------------------------------- obstacles
def test_obstacle_on_the_right_turns_the_evader_left():
    # facing +x at speed 2; obstacle at (50, 46) (right side): F = 400.7 along +y.
    # delta = pi/2 -> closest yaw rate pi/6 (index 4); a_proj = F . (1, 0) / m = 0 -> a = 0 (index 1).
    assert decide([[50.0, 50.0, 0.0, 2.0]], obstacles=[[50.0, 46.0, 1.0]]) == [action(1, 4)]


def test_obstacle_force_is_taken_in_the_ego_frame():
    # facing +y; obstacle at (46, 50) on its left: world force (400.7, 0) -> ego (0, -400.7).
    # delta = -pi/2 -> -pi/6 (index 0); a_proj = 0 -> index 1.
    # (Unrotated it would read (400.7, 0): delta 0, a_proj 0.8 -> brake, action 2.)
    assert decide([[50.0, 50.0, math.pi / 2, 2.0]], obstacles=[[46.0, 50.0, 1.0]]) == [action(1, 0)]


def test_small_push_picks_the_closest_yaw_rate():
    # Obstacle behind-right so that F points at 0.25 rad: |p| = 9.8, d = 9.8 - 1.8 = 8,
    # |F| = 5000 (1/8 - 1/15) / 64 = 4.56. delta = 0.25: |pi/12 - 0.25| = 0.012 beats |0 - 0.25| -> index 3;
    # a_proj = 4.56 cos(0.25) / 500 = 0.0088 -> a = 0 (index 1).
    angle = 0.25
    obstacle = [50.0 - 9.8 * math.cos(angle), 50.0 - 9.8 * math.sin(angle), 1.0]
    assert repulsion(8.0) == pytest.approx(4.557, abs=1e-3)
    assert decide([[50.0, 50.0, 0.0, 2.0]], obstacles=[obstacle]) == [action(1, 3)]


def test_large_push_along_the_velocity_still_brakes():
    # Published quirk: obstacle 4.5 m straight behind, d = 2.7, F = 208.3 forward;
    # a_proj = +0.417 > 0.1 -> index 0 (-0.4) although the push is forward.
    assert repulsion(2.7) == pytest.approx(208.3, abs=0.1)
    assert decide([[50.0, 50.0, 0.0, 2.0]], obstacles=[[45.5, 50.0, 1.0]]) == [action(0, 2)]


def test_large_push_against_the_velocity_brakes_and_turns_hard():
    # obstacle 4.5 m straight ahead: F = -208.3 x; a_proj = -0.417 -> brake;
    # delta = +-pi -> wrapped to -pi -> closest -pi/6 (index 0)
    assert decide([[50.0, 50.0, 0.0, 2.0]], obstacles=[[54.5, 50.0, 1.0]]) == [action(0, 0)]


def test_projection_below_threshold_does_not_brake():
    # obstacle 6.8 m behind: d = 5, F = 5000 (0.2 - 0.0667) / 25 = 26.7; a_proj = 0.053 <= 0.1
    assert repulsion(5.0) == pytest.approx(26.67, abs=0.01)
    assert decide([[50.0, 50.0, 0.0, 2.0]], obstacles=[[43.2, 50.0, 1.0]]) == [action(1, 2)]
    assert decide([[50.0, 50.0, 0.0, 0.5]], obstacles=[[43.2, 50.0, 1.0]]) == [action(2, 2)]


def test_obstacle_beyond_d0_exerts_no_force():
    # |p| = 17, d = 17 - 1.8 = 15.2 >= d0: no force; the slow evader speeds up
    assert decide([[50.0, 50.0, 0.0, 0.5]], obstacles=[[33.0, 50.0, 1.0]]) == [action(2, 2)]


# ---------------------------------------------------------------- robots
BEHIND = [[46.0, 50.0, 0.0, 0.0]]  # a pursuer 4 m behind an evader at (50, 50) facing +x


def test_closing_pursuer_behind_repels():
    # e = (-1, 0); v_ao = ((2, 0) - (3, 0)) . e = 1 >= 0: d = 4 - 0.8 - 0.8 = 2.4,
    # obstacle-style 5000 (1/2.4 - 1/15)/2.4^2 = 303.8 along -e = +x, plus velocity 1*(0.35)/2.4 = 0.146 along +x:
    # a_proj = 0.61 > 0.1 -> brake.
    assert repulsion(2.4) == pytest.approx(303.8, abs=0.1)
    assert decide([[50.0, 50.0, 0.0, 2.0]], pursuers=BEHIND, pursuer_vel=[[3.0, 0.0]]) == [action(0, 2)]


def test_receding_pursuer_exerts_no_force():
    # v_ao = ((2, 0) - (1, 0)) . (-1, 0) = -1 < 0: ignored -> a = 0
    assert decide([[50.0, 50.0, 0.0, 2.0]], pursuers=BEHIND, pursuer_vel=[[1.0, 0.0]]) == [action(1, 2)]


def test_pursuer_with_zero_closing_speed_still_repels():
    # v_ao = 0 >= 0: the obstacle-style force applies (no velocity term) -> a_proj 0.61 -> brake
    assert decide([[50.0, 50.0, 0.0, 2.0]], pursuers=BEHIND, pursuer_vel=[[2.0, 0.0]]) == [action(0, 2)]


def test_collided_pursuer_exerts_no_force():
    assert decide([[50.0, 50.0, 0.0, 2.0]], pursuers=BEHIND, pursuer_vel=[[3.0, 0.0]],
                  pursuer_active=[False]) == [action(1, 2)]


def test_other_evaders_repel_like_pursuers():
    # evader 1 is 4 m behind evader 0 and faster (3 vs 2 m/s).
    # evader 0: as test_closing_pursuer_behind_repels -> brake, straight.
    # evader 1: e = (1, 0), v_ao = (3 - 2) = 1: F = -303.9 x -> a_proj = -0.61 -> brake; delta -pi -> index 0.
    evaders = [[50.0, 50.0, 0.0, 2.0], [46.0, 50.0, 0.0, 3.0]]
    assert decide(evaders) == [action(0, 2), action(0, 0)]


def test_encircled_evader_exerts_no_force():
    evaders = [[50.0, 50.0, 0.0, 2.0], [46.0, 50.0, 0.0, 3.0]]
    assert decide(evaders, evader_active=[True, False])[0] == action(1, 2)


def clearance_for(force: float) -> float:
    """The clearance d at which k_rep (1/d - 1/d0)/d^2 equals `force` (bisection; decreasing in d)."""
    lo, hi = 1.0, 14.9
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if repulsion(mid) > force else (lo, mid)
    return 0.5 * (lo + hi)


def test_velocity_term_adds_to_the_repulsion_of_a_closing_robot():
    # Pursuer ahead with clearance d where the obstacle-style force is 49.95 (a_proj -0.0999, no brake).
    # Coming at -3 m/s: v_ao = (2 - (-3)) = 5 > 0 adds k_v 5 (1/d - 1/d0)/d = 0.2 along -x:
    # |a_proj| = 50.15/500 = 0.1003 > 0.1 -> brake; delta = -pi -> index 0.
    d = clearance_for(49.95)
    velocity_term = 5.0 * (1.0 / d - 1.0 / D0) / d
    assert velocity_term > 0.1
    ahead = [[50.0 + d + 1.6, 50.0, math.pi, 3.0]]
    assert decide([[50.0, 50.0, 0.0, 2.0]], pursuers=ahead, pursuer_vel=[[-3.0, 0.0]]) == [action(0, 0)]


def test_same_robot_without_closing_speed_does_not_tip_the_evader_into_braking():
    # same place, moving with the evader: v_ao = 0 -> only 49.95 -> a_proj = -0.0999 -> a = 0
    d = clearance_for(49.95)
    ahead = [[50.0 + d + 1.6, 50.0, 0.0, 2.0]]
    assert decide([[50.0, 50.0, 0.0, 2.0]], pursuers=ahead, pursuer_vel=[[2.0, 0.0]]) == [action(1, 0)]


# ---------------------------------------------------------------- boundary
def boundary_push(b: float, outside: bool = False) -> float:
    k = K_REP * 20.0 if outside else K_REP
    return k * (1.0 / abs(b) - 1.0 / D0) / abs(b) ** 1.5


def test_boundary_force_is_scaled_by_arena_size():
    # 11 m from the left wall: 5000 (1/11 - 1/15) / 11^1.5 = 3.322, times 10 sqrt(W H)/100:
    # 100 x 100 -> x10 = 33.2 (a_proj 0.066, no brake); 200 x 200 -> x20 = 66.4 (a_proj 0.133, brake).
    assert boundary_push(11.0) == pytest.approx(3.3224, abs=1e-4)
    assert decide([[11.0, 50.0, 0.0, 2.0]], arena=(100.0, 100.0)) == [action(1, 2)]
    assert decide([[11.0, 100.0, 0.0, 2.0]], arena=(200.0, 200.0)) == [action(0, 2)]


def test_near_wall_uses_only_nonzero_yaw_rates_and_ties_go_first():
    # 5 m from the left wall (< d0/2 = 7.5): F = 10 * 5000 (1/5 - 1/15)/5^1.5 = 596.3 along +x = ego +x.
    # delta = 0: -pi/12 and +pi/12 tie at pi/12 -> the first, -pi/12 (index 1); a_proj = 1.19 -> brake.
    assert 10 * boundary_push(5.0) == pytest.approx(596.3, abs=0.1)
    assert decide([[5.0, 50.0, 0.0, 2.0]]) == [action(0, 1)]


def test_just_beyond_half_d0_from_the_wall_all_yaw_rates_are_allowed():
    # 7.6 m from the wall: F = 154.9 along +x -> brake, delta = 0 -> w = 0 (index 2)
    assert decide([[7.6, 50.0, 0.0, 2.0]]) == [action(0, 2)]
    # 7.4 m: near the wall -> nonzero yaw rates only -> the first of the tie, index 1
    assert decide([[7.4, 50.0, 0.0, 2.0]]) == [action(0, 1)]


def test_boundary_force_is_added_unrotated_frame_mix_quirk():
    # Facing +y at (5, 50): world boundary force (596.3, 0) is added as if it were ego-frame.
    # Quirk: F_ego = (596.3, 0): delta = 0 -> nonzero tie -> index 1; a_proj = 1.19 -> brake -> action 1.
    # (Rotated, F_ego = (0, -596.3): delta = -pi/2 -> index 0; a_proj = 0 -> a = 0 -> action 5.)
    assert decide([[5.0, 50.0, math.pi / 2, 2.0]]) == [action(0, 1)]


def test_outside_arena_brakes_when_force_is_along_velocity_frame_mix_quirk():
    # At (-1, 50) facing -x (theta = pi) at 2 m/s: ego velocity (2, 0). b = -1 < 0: k = 5000 * 20,
    # push = 100000 (1 - 1/15) / 1 = 93333 (+x world), x10 = 933333 added unrotated as ego (+x):
    # F . v > 0 -> index 0; delta = 0 -> nonzero tie -> index 1. Action 1.
    # (Rotated it would be ego -x: F . v < 0 -> last index, delta -pi -> index 0: action 10.)
    assert 10 * boundary_push(-1.0, outside=True) == pytest.approx(933333.3, abs=1.0)
    assert decide([[-1.0, 50.0, math.pi, 2.0]]) == [action(0, 1)]


def test_outside_arena_speeds_up_when_force_opposes_velocity():
    # At (101, 50) facing +x: world force -933333 x = ego -x: F . v < 0 -> last index (+0.4);
    # delta = -pi -> among nonzero yaw rates -pi/6 (index 0). Action 10.
    assert decide([[101.0, 50.0, 0.0, 2.0]]) == [action(2, 0)]


def test_boundary_force_is_zero_beyond_d0_from_walls():
    assert decide([[15.5, 15.5, 0.0, 2.0]]) == [action(1, 2)]


def test_world_gives_the_evader_its_scenario_arena():
    # as test_boundary_force_is_added_unrotated_frame_mix_quirk, inside a World of a 100 x 100 arena
    scenario = initial_scenario(
        pursuers=[[60.0, 90.0, 0.0, 0.0], [90.0, 90.0, 0.0, 0.0], [90.0, 60.0, 0.0, 0.0]],
        evaders=[[5.0, 50.0, math.pi / 2, 2.0]],
        arena=(100.0, 100.0),
    )
    world = World(scenario)
    world.reset()
    _, result = world.step(np.full((1, 3), 4))
    assert result.evader_actions.tolist() == [[action(0, 1)]]


# ---------------------------------------------------------------- constant evader
def test_constant_evader_returns_the_same_action_for_everyone():
    state = make_state(PARKED, [[50.0, 50.0, 0.0, 1.0], [20.0, 20.0, 1.0, 2.0]])
    actions = ConstantEvader(13).act(state, geometry_of(state), DEFAULT, ARENA)
    assert actions.tolist() == [[13, 13]]
    assert actions.dtype == np.int64


# ---------------------------------------------------------------- against a plain loop
def reference_apf(state, b: int, j: int, p, arena) -> int:
    """The action of evader j of env b, straight from world.md section 8."""
    width, height = arena
    own, theta = state.evader_xy[b, j], state.evader_theta[b, j]
    v_own = to_ego(theta, state.evader_vel[b, j])
    force = np.zeros(2)

    def nearest(points, radii, active, skip=None):
        found = []
        for k in range(len(points)):
            dist = float(np.hypot(*(points[k] - own)))
            if k != skip and active[k] and dist <= p.perception_radius + radii[k]:
                found.append((dist, k))
        return [k for _, k in sorted(found)[:5]]

    for k in nearest(state.obstacle_xy[b], state.obstacle_r[b], np.ones(state.obstacle_r.shape[1], bool)):
        rel = to_ego(theta, state.obstacle_xy[b, k] - own)
        d = np.hypot(*rel) - state.obstacle_r[b, k] - 0.8
        if d < p.apf_d0:
            force += p.apf_k_rep * (1 / d - 1 / p.apf_d0) / d**p.apf_n * (-rel / np.hypot(*rel))
    robots = [(state.pursuer_xy[b, k], state.pursuer_vel[b, k]) for k in nearest(
        state.pursuer_xy[b], np.full(state.pursuer_xy.shape[1], p.robot_radius), state.pursuer_active[b])]
    robots += [(state.evader_xy[b, k], state.evader_vel[b, k]) for k in nearest(
        state.evader_xy[b], np.full(state.evader_xy.shape[1], p.robot_radius), state.evader_active[b], skip=j)]
    for xy, vel in robots:
        rel = to_ego(theta, xy - own)
        e = rel / np.hypot(*rel)
        v_ao = float(np.dot(v_own - to_ego(theta, vel), e))
        if v_ao >= 0:
            d = np.hypot(*rel) - 0.8 - 0.8
            if d < p.apf_d0:
                force += p.apf_k_rep * (1 / d - 1 / p.apf_d0) / d**p.apf_n * (-e)
                if v_ao > 0:
                    force += -p.apf_k_v * v_ao * (1 / d - 1 / p.apf_d0) / d * e
    walls = [(own[0], 0, 1.0), (width - own[0], 0, -1.0), (own[1], 1, 1.0), (height - own[1], 1, -1.0)]
    boundary = np.zeros(2)
    for dist, axis, inward in walls:
        if dist < p.apf_d0:
            k = p.apf_k_rep * p.apf_k_out if dist < 0 else p.apf_k_rep
            boundary[axis] += inward * k * (1 / abs(dist) - 1 / p.apf_d0) / abs(dist) ** 1.5
    force = force + boundary * p.apf_k_boundary * math.sqrt(width * height) / 100  # unrotated (quirk)

    speed = float(np.hypot(*v_own))
    v_angle = math.atan2(v_own[1], v_own[0]) if speed > 1e-3 else 0.0
    delta = (math.atan2(force[1], force[0]) - v_angle + math.pi) % (2 * math.pi) - math.pi
    outside = any(dist < 0 for dist, _, _ in walls)
    near_wall = any(dist < p.apf_d0 / 2 for dist, _, _ in walls)
    choices = [i for i, w in enumerate(EVADER_YAW_RATES) if w != 0.0 or not near_wall]
    yaw = min(choices, key=lambda i: abs(EVADER_YAW_RATES[i] - delta))
    if outside:
        accel = 0 if float(np.dot(force, v_own)) > 0 else 2
    else:
        unit = v_own / speed if speed > 1e-3 else np.array([1.0, 0.0])
        a_proj = float(np.dot(force / p.apf_mass, unit))
        accel = 0 if abs(a_proj) > p.apf_a_threshold else (2 if speed < p.apf_v_min else 1)
    return accel * 5 + yaw


@pytest.mark.parametrize(("seed", "arena"), [(0, (40.0, 40.0)), (1, (40.0, 30.0)), (2, (30.0, 45.0))])
def test_apf_matches_plain_loop_on_random_worlds(seed, arena):
    rng = np.random.default_rng(seed)
    state = random_state(rng, num_envs=6, num_pursuers=10, num_evaders=6, num_obstacles=10, low=-3.0, high=48.0)
    got = PublishedAPFEvader().act(state, geometry_of(state), DEFAULT, arena)
    expected = np.array([[reference_apf(state, b, j, DEFAULT, arena) for j in range(6)] for b in range(6)])
    np.testing.assert_array_equal(got, expected)
    assert len(np.unique(expected)) >= 5  # the worlds exercise several decisions


# ---------------------------------------------------------------- the registry
def test_the_registry_names_apf_first_then_still_and_widest_gap():
    assert tuple(EVADERS) == ("apf", "still", "widest-gap")
    assert DEFAULT_EVADER == "apf"
    assert all(kind.name == name and kind.summary for name, kind in EVADERS.items())
    assert [type(build_evader(name)) for name in EVADERS] == [PublishedAPFEvader, StillEvader, WidestGapEvader]


def test_an_unknown_evader_lists_the_known_ones():
    with pytest.raises(UnknownEvader, match="unknown evader 'fast'; the evaders are apf, still, widest-gap"):
        build_evader("fast")


def test_a_registered_evader_is_one_a_scenario_can_name(monkeypatch):
    monkeypatch.setattr(terl_rt.sim.evader, "EVADERS", dict(EVADERS))
    register_evader("idle", lambda: ConstantEvader(7), "keeps speed and heading")
    world = World(Scenario.preset("small-11").replace(evader="idle"))
    assert isinstance(world.evader_policy, ConstantEvader) and world.evader_policy.action == 7
    with pytest.raises(ValueError, match="already registered"):
        register_evader("idle", StillEvader, "again")


def test_the_world_builds_the_evader_its_scenario_names():
    scenario = Scenario.preset("small-11")
    assert type(World(scenario).evader_policy) is PublishedAPFEvader
    assert type(World(scenario.replace(evader="still")).evader_policy) is StillEvader
    assert type(World(scenario.replace(evader="widest-gap")).evader_policy) is WidestGapEvader
    # an explicit policy still wins
    assert type(World(scenario.replace(evader="still"), evader_policy=ConstantEvader(7)).evader_policy) is ConstantEvader


# ---------------------------------------------------------------- still targets
STILL_PURSUERS = [[20.0, 20.0, 0.0, 0.0], [100.0, 20.0, 0.0, 0.0], [20.0, 100.0, 0.0, 0.0]]


def test_a_still_target_at_rest_does_not_move():
    # a = -0.4, w = 0 from rest: the speed stays clipped at 0, and without cores no current moves it
    scenario = initial_scenario(STILL_PURSUERS, [[60.0, 60.0, 1.0, 0.0]], evader="still")
    world = World(scenario)
    world.reset()
    for _ in range(20):
        _, result = world.step(np.full((1, 3), 4))
        assert result.evader_actions.tolist() == [[2]]
    assert world.state.evader_xy.tolist() == [[[60.0, 60.0]]]
    assert world.state.evader_theta.tolist() == [[1.0]]


def test_a_moving_still_target_comes_to_rest_and_stays():
    # 3.5 m/s braking at 0.4 m/s^2 (and drag) is at rest within 3.5 / 0.4 = 8.75 s = 18 steps
    scenario = initial_scenario(STILL_PURSUERS, [[60.0, 60.0, 0.0, 3.5]], evader="still")
    world = World(scenario)
    world.reset()
    for _ in range(18):
        world.step(np.full((1, 3), 4))
    assert world.state.evader_speed.tolist() == [[0.0]]
    rest = world.state.evader_xy.copy()
    world.step(np.full((1, 3), 4))
    assert np.array_equal(world.state.evader_xy, rest)


# ---------------------------------------------------------------- widest gap
def test_the_bisector_of_the_widest_gap_on_paper():
    # pursuers at bearings 0, 90 and 135 degrees leave gaps of 90, 45 and 225 (135 -> 360):
    # the bisector of the widest is 135 + 225 / 2 = 247.5 degrees
    bearing = np.radians([[[0.0, 90.0, 135.0, 0.0, 0.0]]])
    seen = np.array([[[True, True, True, False, False]]])
    assert math.degrees(widest_gap_bisector(bearing, seen)[0, 0]) == pytest.approx(247.5)


def test_one_pursuer_leaves_one_gap_whose_bisector_points_away():
    bearing = np.radians([[[30.0, 0.0]]])
    assert math.degrees(widest_gap_bisector(bearing, np.array([[[True, False]]]))[0, 0]) == pytest.approx(210.0)


def test_equal_gaps_go_to_the_one_from_the_smallest_bearing():
    # bearings -90 and 90: two gaps of 180; the one from -90 wins, bisector 0
    bearing = np.radians([[[90.0, -90.0]]])
    assert widest_gap_bisector(bearing, np.ones((1, 1, 2), bool))[0, 0] == pytest.approx(0.0)


def reference_bisector(bearings: list[float]) -> float:
    """The widest gap's bisector by a plain loop over the sorted bearings (rad)."""
    ordered = sorted(bearings)
    best, start = -1.0, 0.0
    for i, b in enumerate(ordered):
        gap = (ordered[i + 1] if i + 1 < len(ordered) else ordered[0] + 2 * math.pi) - b
        if gap > best:
            best, start = gap, b
    return start + best / 2


def test_widest_gap_bisector_matches_a_plain_loop_on_random_bearings():
    rng = np.random.default_rng(3)
    bearing = rng.uniform(-math.pi, math.pi, (40, 3, 5))
    seen = rng.random((40, 3, 5)) < 0.6
    seen[:, :, 0] = True  # the caller masks rows without a seen pursuer
    got = widest_gap_bisector(bearing, seen)
    expected = [[reference_bisector(bearing[b, j][seen[b, j]].tolist()) for j in range(3)] for b in range(40)]
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)


def gap_decision(evader, pursuers, obstacles=()) -> int:
    state = make_state(pursuers, [evader], obstacles)
    return WidestGapEvader().act(state, geometry_of(state), DEFAULT, (120.0, 120.0))[0, 0].item()


GAP_RING = ring((60.0, 60.0), 10.0, [0.0, 90.0, 135.0])
"""pursuers 10 m from (60, 60) at bearings 0, 90 and 135 degrees: the widest gap's bisector is 247.5."""


def test_the_gap_seeker_turns_towards_the_bisector_at_full_speed():
    # heading 237.5 degrees: the bisector (247.5) lies 10 degrees (0.175 rad) to its left. Turns in one
    # 0.5 s step: w / 2 = -0.262, -0.131, 0, 0.131, 0.262 rad -> pi/12 (index 3); within pi/2 -> +0.4
    assert gap_decision([60.0, 60.0, math.radians(237.5), 2.0], GAP_RING) == action(2, 3)
    # heading 257.5 degrees: 10 degrees to its right -> -pi/12 (index 1)
    assert gap_decision([60.0, 60.0, math.radians(257.5), 2.0], GAP_RING) == action(2, 1)


def test_the_gap_seeker_brakes_and_turns_hard_when_the_gap_is_behind():
    # heading 0: the bisector lies 112.5 degrees to its right -> -pi/6 (index 0); beyond pi/2 -> -0.4
    assert gap_decision([60.0, 60.0, 0.0, 2.0], GAP_RING) == action(0, 0)


def test_the_gap_seeker_ignores_pursuers_beyond_its_sensing_range():
    # one pursuer 10 m behind (seen) and one 25 m ahead (beyond R + r = 21.1 m): the one gap's
    # bisector is straight ahead -> w = 0, +0.4. Seeing both, the tie would turn it to 90 degrees.
    assert gap_decision([60.0, 60.0, 0.0, 2.0], [[50.0, 60.0, 0.0, 0.0], [85.0, 60.0, 0.0, 0.0]]) == action(2, 2)


def test_the_gap_seeker_seeing_no_pursuer_holds_its_course():
    # no pursuer within 21.1 m: the pull is along its heading; speed 2 >= v_min -> a = 0; 0.5 < v_min -> +0.4
    assert gap_decision([60.0, 60.0, 1.0, 2.0], [[10.0, 10.0, 0.0, 0.0]]) == action(1, 2)
    assert gap_decision([60.0, 60.0, 1.0, 0.5], [[10.0, 10.0, 0.0, 0.0]]) == action(2, 2)


def test_the_gap_seeker_turns_away_from_an_obstacle_ahead():
    # gap straight ahead (one pursuer behind); obstacle at (63, 59), r = 1: |p| = 3.162, d = 1.362,
    # push 5000 (1/1.362 - 1/15) / 1.362^2 = 1805 along (-0.949, 0.316); with the pull 50 along +x the
    # total points at 161 degrees: -> pi/6 (index 4) and, beyond pi/2, -0.4
    evader, behind = [60.0, 60.0, 0.0, 2.0], [[50.0, 60.0, 0.0, 0.0]]
    assert gap_decision(evader, behind, obstacles=[[63.0, 59.0, 1.0]]) == action(0, 4)
    assert gap_decision(evader, behind) == action(2, 2)


def test_the_same_seed_gives_the_same_gap_seeking_episode():
    scenario = Scenario.preset("small-11").replace(evader="widest-gap", max_steps=40)
    runs = []
    for _ in range(2):
        world = World(scenario, num_envs=2, seed=5)
        world.reset()
        while not world.done.any():
            _, result = world.step(np.full((2, 11), 7))
        runs.append((world.state.evader_xy.copy(), result.evader_actions.copy()))
    assert np.array_equal(runs[0][0], runs[1][0]) and np.array_equal(runs[0][1], runs[1][1])
