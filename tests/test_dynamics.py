"""Robot kinematics and Rankine vortex currents (world.md sections 2-3)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sim_helpers import PURSUER_IDLE, far_row, initial_scenario

from terl_rt.sim.actions import EVADER_ACTIONS, PURSUER_ACTIONS
from terl_rt.sim.dynamics import integrate, signed_circulation
from terl_rt.sim.evader import ConstantEvader
from terl_rt.sim.world import World

DT = 0.05
K_PURSUER = 0.4 / 3.0  # drag k = max(a_set) / s_max, 1/s
R0 = 0.5


def step(
    x: float, y: float, theta: float, speed: float, a: float = 0.0, w: float = 0.0, *,
    substeps: int = 10, dt: float = DT, cores=(), max_speed: float = 3.0, drag: float = K_PURSUER,
    moving: bool = True,
):
    """One robot, one decision step: returns (x, y, theta, speed, vx, vy) as floats.

    cores: rows [cx, cy, gamma, clockwise]."""
    core = np.array(cores, float).reshape(1, len(cores), 4)
    xy, th, s, vel = integrate(
        np.array([[[x, y]]], float), np.array([[theta]]), np.array([[speed]]),
        np.array([[a]]), np.array([[w]]), np.array([[moving]]),
        np.array([max_speed]), np.array([drag]),
        np.ascontiguousarray(core[..., :2]), signed_circulation(core[..., 2], core[..., 3] > 0.5),
        R0, dt, substeps,
    )
    return (float(xy[0, 0, 0]), float(xy[0, 0, 1]), float(th[0, 0]), float(s[0, 0]),
            float(vel[0, 0, 0]), float(vel[0, 0, 1]))


def current_at(x: float, y: float, cores) -> tuple[float, float]:
    """The current at (x, y): a robot at rest drifts with it; one sub-step of 1 s moves it by c."""
    nx, ny, _, _, vx, vy = step(x, y, 0.0, 0.0, substeps=1, dt=1.0, cores=cores)
    assert (nx - x, ny - y) == pytest.approx((vx, vy), abs=1e-12)
    return vx, vy


# ---------------------------------------------------------------- action tables
def test_pursuer_action_index_is_acceleration_major():
    # index = i_a * 3 + i_w: 5 = (a index 1 -> 0.0, w index 2 -> +pi/6)
    assert PURSUER_ACTIONS.shape == (9, 2)
    assert PURSUER_ACTIONS[5] == pytest.approx([0.0, math.pi / 6])
    assert PURSUER_ACTIONS[0] == pytest.approx([-0.4, -math.pi / 6])
    assert PURSUER_ACTIONS[8] == pytest.approx([0.4, math.pi / 6])


def test_evader_action_index_is_acceleration_major():
    # index = i_a * 5 + i_w: 13 = (a index 2 -> 0.4, w index 3 -> +pi/12)
    assert EVADER_ACTIONS.shape == (15, 2)
    assert EVADER_ACTIONS[13] == pytest.approx([0.4, math.pi / 12])
    assert EVADER_ACTIONS[1] == pytest.approx([-0.4, -math.pi / 12])
    assert EVADER_ACTIONS[7] == pytest.approx([0.0, 0.0])


# ---------------------------------------------------------------- kinematics
def test_one_substep_moves_with_old_speed_then_updates_speed_and_heading():
    # v = 1 * (cos 0, sin 0) = (1, 0); x = 0 + 1 * 0.05 = 0.05
    # s = 1 + (0.4 - (0.4/3) * 1) * 0.05 = 1 + 0.26667 * 0.05 = 1.013333
    # theta = 0 + (pi/6) * 0.05 = pi/120
    x, y, theta, s, vx, vy = step(0.0, 0.0, 0.0, 1.0, a=0.4, w=math.pi / 6, substeps=1)
    assert (x, y) == pytest.approx((0.05, 0.0), abs=1e-12)
    assert s == pytest.approx(1.0 + (0.4 - K_PURSUER) * 0.05, abs=1e-12)
    assert theta == pytest.approx(math.pi / 120, abs=1e-12)
    assert (vx, vy) == pytest.approx((1.0, 0.0), abs=1e-12)


def test_full_step_at_top_speed_goes_straight_for_half_a_second():
    # a = 0.4 balances drag at s_max: 0.4 - (0.4/3) * 3 = 0, so s stays 3 m/s;
    # 10 sub-steps * 0.05 s * 3 m/s = 1.5 m along theta = 0.
    x, y, theta, s, vx, vy = step(10.0, 20.0, 0.0, 3.0, a=0.4)
    assert (x, y) == pytest.approx((11.5, 20.0), abs=1e-12)
    assert s == pytest.approx(3.0, abs=1e-12)
    assert theta == 0.0
    assert (vx, vy) == pytest.approx((3.0, 0.0), abs=1e-12)


def test_drag_slows_a_coasting_robot():
    # a = 0: s_{k+1} = s_k (1 - k dt) with k dt = (0.4/3) * 0.05 = 1/150.
    # s_10 = 3 (149/150)^10 = 2.80589; x = sum_k 3 (149/150)^k 0.05 = 22.5 (1 - (149/150)^10) = 1.45580.
    q = 149.0 / 150.0
    x, y, theta, s, vx, _ = step(0.0, 0.0, 0.0, 3.0, a=0.0)
    assert s == pytest.approx(3.0 * q**10, rel=1e-12)
    assert x == pytest.approx(22.5 * (1.0 - q**10), rel=1e-12)
    assert x == pytest.approx(1.45580, abs=1e-5)
    # the reported velocity is the one of sub-step 10, moved with speed s_9
    assert vx == pytest.approx(3.0 * q**9, rel=1e-12)


def test_speed_is_clipped_at_s_max():
    # with s_max = 1: s = 1 + (0.4 - (0.4/3) * 1) * 0.05 = 1.0133 > 1 -> clipped to 1.0
    _, _, _, s, _, _ = step(0.0, 0.0, 0.0, 1.0, a=0.4, substeps=1, max_speed=1.0)
    assert s == 1.0


def test_speed_never_exceeds_s_max_under_full_acceleration():
    _, _, _, s, vx, vy = step(0.0, 0.0, 0.0, 2.99, a=0.4, substeps=10)
    assert s <= 3.0
    assert math.hypot(vx, vy) <= 3.0


def test_speed_follows_the_per_substep_clip_even_with_stiff_drag():
    # k = 10 /s, dt = 0.25 s (k dt = 2.5), s_max = 0.04, a = 0, s = 0.04:
    # sub-step 1: 0.04 + (0 - 10 * 0.04) * 0.25 = -0.06 -> 0; sub-step 2: 0 + 0 = 0.
    _, _, _, s, _, _ = step(0.0, 0.0, 0.0, 0.04, a=0.0, substeps=2, dt=0.25, max_speed=0.04, drag=10.0)
    assert s == 0.0


def test_speed_is_clipped_at_zero_when_braking():
    # s = 0.01 + (-0.4 - (0.4/3) * 0.01) * 0.05 = -0.0100667 -> 0; it moved 0.01 * 0.05 = 0.0005 m first.
    x, _, _, s, vx, vy = step(0.0, 0.0, 0.0, 0.01, a=-0.4)
    assert s == 0.0
    assert x == pytest.approx(0.0005, abs=1e-15)
    assert (vx, vy) == (0.0, 0.0)


def test_turning_step_follows_the_heading_of_each_substep():
    # s stays 3 (a balances drag); theta_k = k * (pi/6) * 0.05 = k pi/120 at the start of sub-step k;
    # x = sum_{k<10} 3 cos(k pi/120) 0.05, y = sum_{k<10} 3 sin(k pi/120) 0.05; theta_10 = pi/12.
    x, y, theta, s, _, _ = step(0.0, 0.0, 0.0, 3.0, a=0.4, w=math.pi / 6)
    expected_x = sum(0.15 * math.cos(k * math.pi / 120) for k in range(10))
    expected_y = sum(0.15 * math.sin(k * math.pi / 120) for k in range(10))
    assert (x, y) == pytest.approx((expected_x, expected_y), abs=1e-12)
    assert theta == pytest.approx(math.pi / 12, abs=1e-12)
    assert s == pytest.approx(3.0, abs=1e-12)


def test_reported_velocity_is_the_last_substeps_not_the_final_heading():
    # the last sub-step moves with theta_9 = 9 pi/120, not theta_10 = pi/12.
    _, _, theta, _, vx, vy = step(0.0, 0.0, 0.0, 3.0, a=0.4, w=math.pi / 6)
    assert (vx, vy) == pytest.approx((3 * math.cos(9 * math.pi / 120), 3 * math.sin(9 * math.pi / 120)), abs=1e-12)
    assert math.atan2(vy, vx) != pytest.approx(theta, abs=1e-3)


def test_heading_wraps_past_2pi_to_small_angle():
    # (2pi - 0.01) + (pi/6) * 0.5 = 2pi + pi/12 - 0.01 -> pi/12 - 0.01 = 0.25180
    _, _, theta, _, _, _ = step(0.0, 0.0, 2 * math.pi - 0.01, 1.0, w=math.pi / 6)
    assert theta == pytest.approx(math.pi / 12 - 0.01, abs=1e-12)


def test_heading_wraps_below_zero_to_near_2pi():
    # 0.01 - (pi/6) * 0.5 = 0.01 - pi/12 < 0 -> 2pi + 0.01 - pi/12 = 6.04160
    _, _, theta, _, _, _ = step(0.0, 0.0, 0.01, 1.0, w=-math.pi / 6)
    assert theta == pytest.approx(2 * math.pi + 0.01 - math.pi / 12, abs=1e-12)
    assert 0.0 <= theta < 2 * math.pi


def test_heading_stays_in_0_2pi_over_many_random_steps():
    rng = np.random.default_rng(3)
    b, r = 4, 12
    theta = rng.uniform(0, 2 * np.pi, (b, r))
    xy, speed = rng.uniform(0, 50, (b, r, 2)), rng.uniform(0, 3, (b, r))
    for _ in range(60):
        control = PURSUER_ACTIONS[rng.integers(0, 9, (b, r))]
        xy, theta, speed, _ = integrate(
            xy, theta, speed, control[..., 0], control[..., 1], np.ones((b, r), bool),
            np.full(r, 3.0), np.full(r, K_PURSUER), np.zeros((b, 0, 2)), np.zeros((b, 0)), R0, DT, 10,
        )
        xy = np.ascontiguousarray(xy)
        assert np.all((theta >= 0) & (theta < 2 * np.pi))
        assert np.all((speed >= 0) & (speed <= 3.0))


def test_frozen_robot_keeps_its_state_and_has_zero_velocity():
    x, y, theta, s, vx, vy = step(5.0, 6.0, 1.0, 2.0, a=0.4, w=math.pi / 6, moving=False,
                                  cores=[[6.0, 6.0, 2 * math.pi, 1.0]])
    assert (x, y, theta, s) == (5.0, 6.0, 1.0, 2.0)
    assert (vx, vy) == (0.0, 0.0)


def test_integration_matches_plain_loop_with_currents():
    # A plain per-robot, per-sub-step loop of world.md section 2 with section 3's currents.
    rng = np.random.default_rng(11)
    b, r, v = 3, 5, 4
    xy = rng.uniform(0, 20, (b, r, 2))
    theta = rng.uniform(0, 2 * np.pi, (b, r))
    speed = rng.uniform(0, 3, (b, r))
    accel = rng.choice([-0.4, 0.0, 0.4], (b, r))
    yaw = rng.choice([-np.pi / 6, 0.0, np.pi / 6], (b, r))
    moving = rng.random((b, r)) < 0.8
    max_speed = np.array([3.0, 3.0, 3.0, 3.5, 3.5])
    drag = 0.4 / max_speed
    core_xy = rng.uniform(0, 20, (b, v, 2))
    gamma = rng.uniform(2.0, 8.0, (b, v))
    clockwise = rng.random((b, v)) < 0.5
    got = integrate(xy, theta, speed, accel, yaw, moving, max_speed, drag, core_xy,
                    signed_circulation(gamma, clockwise), R0, DT, 10)

    def current(px, py, e):
        cx, cy = 0.0, 0.0
        for c in range(v):
            dx, dy = core_xy[e, c, 0] - px, core_xy[e, c, 1] - py
            d = math.hypot(dx, dy)
            ux, uy = dx / d, dy / d
            sp = gamma[e, c] * d / (2 * math.pi * R0**2) if d <= R0 else gamma[e, c] / (2 * math.pi * d)
            rx, ry = (-uy, ux) if clockwise[e, c] else (uy, -ux)  # [[0,-1],[1,0]] u or [[0,1],[-1,0]] u
            cx, cy = cx + sp * rx, cy + sp * ry
        return cx, cy

    for e in range(b):
        for i in range(r):
            px, py, th, s = xy[e, i, 0], xy[e, i, 1], theta[e, i], speed[e, i]
            vx = vy = 0.0
            if moving[e, i]:
                for _ in range(10):
                    cx, cy = current(px, py, e)
                    vx, vy = s * math.cos(th) + cx, s * math.sin(th) + cy
                    px, py = px + vx * DT, py + vy * DT
                    s = min(max(s + (accel[e, i] - drag[i] * s) * DT, 0.0), max_speed[i])
                    th = (th + yaw[e, i] * DT) % (2 * math.pi)
            assert got[0][e, i] == pytest.approx([px, py], abs=1e-9)
            assert got[1][e, i] == pytest.approx(th, abs=1e-9)
            assert got[2][e, i] == pytest.approx(s, abs=1e-12)
            assert got[3][e, i] == pytest.approx([vx, vy], abs=1e-9)


# ---------------------------------------------------------------- vortex currents
def test_current_beyond_core_is_gamma_over_2pi_d():
    # Gamma = 2 pi, d = 2: speed = 2pi / (2pi * 2) = 0.5. Point at core + (2, 0): u = (-1, 0);
    # clockwise Rot = [[0,-1],[1,0]]: Rot u = (0, -1) -> c = (0, -0.5).
    assert current_at(12.0, 10.0, [[10.0, 10.0, 2 * math.pi, 1.0]]) == pytest.approx((0.0, -0.5), abs=1e-12)


def test_current_inside_core_grows_linearly_with_distance():
    # d = 0.25 <= r0 = 0.5: speed = Gamma d / (2 pi r0^2) = 2pi * 0.25 / (2pi * 0.25) = 1.0; direction (0, -1).
    assert current_at(10.25, 10.0, [[10.0, 10.0, 2 * math.pi, 1.0]]) == pytest.approx((0.0, -1.0), abs=1e-12)


def test_current_at_core_edge_is_gamma_over_2pi_r0():
    # d = r0 = 0.5: both formulas give 2pi / (2pi * 0.5) = 2.0 m/s.
    assert current_at(10.5, 10.0, [[10.0, 10.0, 2 * math.pi, 1.0]]) == pytest.approx((0.0, -2.0), abs=1e-12)


def test_current_at_core_centre_is_zero():
    assert current_at(10.0, 10.0, [[10.0, 10.0, 2 * math.pi, 1.0]]) == pytest.approx((0.0, 0.0), abs=1e-12)


def test_counterclockwise_core_turns_the_other_way():
    # not clockwise: Rot = [[0,1],[-1,0]]: Rot (-1, 0) = (0, 1) -> c = (0, 0.5).
    assert current_at(12.0, 10.0, [[10.0, 10.0, 2 * math.pi, 0.0]]) == pytest.approx((0.0, 0.5), abs=1e-12)


def test_clockwise_core_circulates_clockwise():
    # above the core, a clockwise flow goes towards +x: u = (0, -1), Rot u = (1, 0).
    assert current_at(10.0, 13.0, [[10.0, 10.0, 3 * 2 * math.pi, 1.0]]) == pytest.approx((1.0, 0.0), abs=1e-12)


def test_currents_of_several_cores_add():
    # At (0, 0): core A (2, 0), Gamma 2pi, clockwise: u = (1, 0), Rot u = (0, 1), speed 0.5 -> (0, 0.5);
    # core B (0, 4), Gamma 4pi, not clockwise: u = (0, 1), Rot u = (1, 0), speed 4pi/(2pi*4) = 0.5 -> (0.5, 0).
    cores = [[2.0, 0.0, 2 * math.pi, 1.0], [0.0, 4.0, 4 * math.pi, 0.0]]
    assert current_at(0.0, 0.0, cores) == pytest.approx((0.5, 0.5), abs=1e-12)


def test_no_cores_means_no_current():
    assert current_at(3.0, 4.0, []) == (0.0, 0.0)


def test_current_drifts_a_robot_at_rest_over_a_step():
    # 10 sub-steps of 0.05 s in a uniform-looking far field: d = 50, speed 2pi/(2pi*50) = 0.02 m/s;
    # the point moves about 0.01 m in the -y direction (clockwise, point at core + (50, 0)).
    x, y, _, s, vx, vy = step(60.0, 10.0, 0.0, 0.0, cores=[[10.0, 10.0, 2 * math.pi, 1.0]])
    assert s == 0.0
    assert y == pytest.approx(10.0 - 0.01, abs=1e-6)
    assert x == pytest.approx(60.0, abs=1e-5)
    assert (vx, vy) == pytest.approx((0.0, -0.02), abs=1e-5)  # the direction turns by ~0.009/50 rad


def test_reset_velocity_is_the_steer_velocity_without_the_current():
    # world.md section 2: the published simulator computes the reset velocity before the cores exist.
    # Pursuer 0 at (50, 50), heading pi/2, speed 1: steer (0, 1). A core 2 m away at (52, 50), Gamma 2pi,
    # clockwise, would add (0, 0.5) (u = (1, 0), Rot u = (0, 1), speed 2pi / (2pi * 2)): it is left out.
    scenario = initial_scenario(
        pursuers=[[50.0, 50.0, math.pi / 2, 1.0], [10.0, 100.0, 0.0, 2.0], [100.0, 10.0, math.pi, 0.0]],
        evaders=[[80.0, 80.0, 0.0, 3.0]],
        vortices=[[52.0, 50.0, 2 * math.pi, 1.0]],
    )
    world = World(scenario)
    obs = world.reset()
    vel = world.state.pursuer_vel[0]
    assert vel[0] == pytest.approx([0.0, 1.0], abs=1e-12)
    assert vel[1] == pytest.approx([2.0, 0.0], abs=1e-12)
    assert world.state.evader_vel[0, 0] == pytest.approx([3.0, 0.0], abs=1e-12)
    # the first observation sees it: ego velocity in the ego frame is (s, 0)
    assert obs.ego[0, 0, :2] == pytest.approx([1.0, 0.0], abs=1e-6)
    # the first move does feel the current: after one step pursuer 0 moved with it
    world.step(np.array([[PURSUER_IDLE] * 3]))
    assert world.state.pursuer_vel[0, 0, 1] > 1.0


def test_evader_uses_its_own_top_speed_and_drag():
    # evader: s_max 3.5, k = 0.4/3.5, so a = 0.4 at 3.5 m/s balances drag: 3.5 * 0.5 = 1.75 m per step;
    # pursuer: 3 m/s -> 1.5 m. Action 12 of the evader = (0.4, 0); action 7 of the pursuer = (0.4, 0).
    scenario = initial_scenario(
        pursuers=[[10.0, 10.0, 0.0, 3.0], far_row(1), far_row(2)],
        evaders=[[50.0, 50.0, 0.0, 3.5]],
    )
    world = World(scenario, evader_policy=ConstantEvader(12))
    world.reset()
    world.step(np.array([[7, 4, 4]]))
    assert world.state.pursuer_xy[0, 0] == pytest.approx([11.5, 10.0], abs=1e-9)
    assert world.state.evader_xy[0, 0] == pytest.approx([51.75, 50.0], abs=1e-9)
    assert world.state.evader_speed[0, 0] == pytest.approx(3.5, abs=1e-12)
