"""Per-pursuer reward terms (world.md section 9), the `paper` variant's formulas."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sim_helpers import DEFAULT, PURSUER_IDLE, far_row, geometry_of, initial_scenario, make_state, random_state, ring

from terl_rt.sim.encirclement import encircle, remember_perceived
from terl_rt.sim.evader import ConstantEvader
from terl_rt.sim.reward import REWARD_TERMS, paper_reward_terms
from terl_rt.sim.world import World

ARENA = (100.0, 100.0)
EVADER = [50.0, 50.0, 0.0, 0.0]


def terms(state, collided=None, recipients=None) -> dict[str, np.ndarray]:
    """Reward terms of env 0 by name -> [N]. `state.pursuer_active` is the state after collisions;
    recipients default to the pursuers active at the step start (active or collided now)."""
    n = state.pursuer_active.shape[1]
    collided = np.zeros((1, n), bool) if collided is None else np.array([collided], bool)
    recipients = state.pursuer_active | collided if recipients is None else np.array([recipients], bool)
    geometry = geometry_of(state)
    remember_perceived(state, geometry, DEFAULT, state.pursuer_active)
    out, team = paper_reward_terms(
        state.pursuer_xy, recipients, state.pursuer_active, collided, state.evader_active,
        state.obstacle_r, geometry, encircle(state, geometry, DEFAULT, state.pursuer_active), DEFAULT, ARENA,
    )
    return {**{name: out[0, :, i] for i, name in enumerate(REWARD_TERMS)}, "team": float(team[0])}


def test_reward_terms_are_named_in_order():
    assert REWARD_TERMS == ("time", "collision", "emergency", "guidance", "cooperation", "boundary", "completion")


def test_time_penalty_is_minus_one_per_acting_pursuer():
    state = make_state([[20.0, 20.0, 0.0, 0.0], [80.0, 80.0, 0.0, 0.0]], [EVADER])
    assert terms(state)["time"].tolist() == [-1.0, -1.0]


def test_pursuer_inactive_at_step_start_gets_nothing():
    state = make_state([[20.0, 20.0, 0.0, 0.0], [80.0, 80.0, 0.0, 0.0]], [EVADER], pursuer_active=[True, False])
    got = terms(state, recipients=[True, False])
    for name in REWARD_TERMS:
        assert got[name][1] == 0.0, name


def test_collision_costs_80_in_the_step_it_happens():
    state = make_state([[20.0, 20.0, 0.0, 0.0], [80.0, 80.0, 0.0, 0.0]], [EVADER], pursuer_active=[False, True])
    assert terms(state, collided=[True, False])["collision"].tolist() == [-80.0, 0.0]


# ---------------------------------------------------------------- emergency (< d_safe = 4 m)
def test_teammate_closer_than_d_safe_is_an_emergency_for_both():
    state = make_state([[20.0, 20.0, 0.0, 0.0], [23.9, 20.0, 0.0, 0.0]], [EVADER])
    assert terms(state)["emergency"].tolist() == [-5.0, -5.0]


def test_teammate_at_exactly_d_safe_is_no_emergency():
    state = make_state([[20.0, 20.0, 0.0, 0.0], [24.0, 20.0, 0.0, 0.0]], [EVADER])
    assert terms(state)["emergency"].tolist() == [0.0, 0.0]


def test_collided_teammate_is_no_emergency():
    state = make_state([[20.0, 20.0, 0.0, 0.0], [22.0, 20.0, 0.0, 0.0]], [EVADER], pursuer_active=[True, False])
    assert terms(state, recipients=[True, False])["emergency"][0] == 0.0


def test_evader_closer_than_d_safe_is_an_emergency():
    state = make_state([[46.1, 50.0, 0.0, 0.0], [80.0, 80.0, 0.0, 0.0]], [EVADER])
    assert terms(state)["emergency"].tolist() == [-5.0, 0.0]


def test_encircled_evader_is_no_emergency():
    state = make_state([[47.0, 50.0, 0.0, 0.0]], [EVADER, [90.0, 90.0, 0.0, 0.0]], evader_active=[False, True])
    assert terms(state)["emergency"].tolist() == [0.0]


def test_obstacle_centre_closer_than_d_safe_is_an_emergency():
    state = make_state([[20.0, 20.0, 0.0, 0.0], [80.0, 80.0, 0.0, 0.0]], [EVADER], [[20.0, 23.9, 1.0]])
    assert terms(state)["emergency"].tolist() == [-5.0, 0.0]


# ---------------------------------------------------------------- guidance
def test_guidance_is_full_within_d_encircle():
    # d_e = 8 <= d_encircle: +5
    state = make_state([[42.0, 50.0, 0.0, 0.0]], [EVADER])
    assert terms(state)["guidance"][0] == pytest.approx(5.0)


def test_guidance_decays_exponentially_beyond_d_encircle():
    # d_e = 28: 5 exp(-0.05 (28 - 8)) = 5 / e = 1.8394
    state = make_state([[22.0, 50.0, 0.0, 0.0]], [EVADER])
    assert terms(state)["guidance"][0] == pytest.approx(5.0 * math.exp(-1.0))


def test_guidance_sums_over_every_active_evader():
    # evaders at 8 m (+5) and 28 m (+5/e); a third, encircled, at 4 m counts for nothing
    state = make_state([[50.0, 50.0, 0.0, 0.0]], [[58.0, 50.0, 0.0, 0.0], [50.0, 78.0, 0.0, 0.0], [46.0, 50.0, 0.0, 0.0]],
                       evader_active=[True, True, False])
    assert terms(state)["guidance"][0] == pytest.approx(5.0 + 5.0 * math.exp(-1.0))


# ---------------------------------------------------------------- cooperation
def around(count: int, radius: float = 12.0, extra=()):
    """`count` pursuers at `radius` m around the evader (spread on a half circle, no ring forms
    within d_encircle), plus `extra` rows."""
    bearings = [180.0 * k / max(count - 1, 1) for k in range(count)]
    return ring(EVADER[:2], radius, bearings) + list(extra)


def test_three_pursuers_around_an_evader_get_5_each():
    # P = 3: 5 max(0, 1 - 0.3 * 0) = 5; a pursuer 30 m away is not one of them
    state = make_state(around(3, extra=[[50.0, 80.0, 0.0, 0.0]]), [EVADER])
    assert terms(state)["cooperation"].tolist() == pytest.approx([5.0, 5.0, 5.0, 0.0])


def test_four_pursuers_around_an_evader_get_3_5_each():
    # P = 4: 5 (1 - 0.3) = 3.5
    state = make_state(around(4), [EVADER])
    assert terms(state)["cooperation"].tolist() == pytest.approx([3.5] * 4)


def test_five_pursuers_around_an_evader_are_crowding():
    # P >= 5: -10 each
    state = make_state(around(5), [EVADER])
    assert terms(state)["cooperation"].tolist() == pytest.approx([-10.0] * 5)


def test_two_pursuers_around_an_evader_get_no_cooperation():
    state = make_state(around(2), [EVADER])
    assert terms(state)["cooperation"].tolist() == [0.0, 0.0]


def test_cooperation_counts_pursuers_at_exactly_related_distance():
    state = make_state(around(3, radius=18.0), [EVADER])
    assert terms(state)["cooperation"].tolist() == pytest.approx([5.0] * 3)


def test_collided_pursuer_is_not_counted_around_an_evader():
    # four around, one collided this step: P = 3 -> the three active get 5; the collided one nothing
    state = make_state(around(4), [EVADER], pursuer_active=[True, True, True, False])
    got = terms(state, collided=[False, False, False, True])
    assert got["cooperation"].tolist() == pytest.approx([5.0, 5.0, 5.0, 0.0])


def test_imbalance_penalises_every_pursuer():
    # evader A has P = 6 (> 5), evader B (far) has P = 0 (< 3): every pursuer gets -10 more;
    # A's six also get the crowding -10.
    far = [[10.0, 90.0, 0.0, 0.0]]
    state = make_state(around(6, extra=far), [EVADER, [90.0, 10.0, 0.0, 0.0]])
    got = terms(state)
    assert got["cooperation"].tolist() == pytest.approx([-20.0] * 6 + [-10.0])
    assert got["team"] == -10.0  # the imbalance: the share every pursuer gets alike


def test_no_imbalance_when_the_crowd_is_exactly_five():
    far = [[10.0, 90.0, 0.0, 0.0]]
    state = make_state(around(5, extra=far), [EVADER, [90.0, 10.0, 0.0, 0.0]])
    got = terms(state)
    assert got["cooperation"].tolist() == pytest.approx([-10.0] * 5 + [0.0])
    assert got["team"] == 0.0  # the crowd's -10 is its own, not the team's


def test_encircled_evader_causes_no_imbalance():
    # B (P = 0) is already encircled, so only A (P = 6) counts
    far = [[10.0, 90.0, 0.0, 0.0]]
    state = make_state(around(6, extra=far), [EVADER, [90.0, 10.0, 0.0, 0.0]], evader_active=[True, False])
    assert terms(state)["cooperation"].tolist() == pytest.approx([-10.0] * 6 + [0.0])


# ---------------------------------------------------------------- boundary
def test_boundary_penalty_only_outside_the_arena():
    pursuers = [[-0.1, 50.0, 0.0, 0.0], [0.0, 50.0, 0.0, 0.0], [100.1, 50.0, 0.0, 0.0], [50.0, 100.5, 0.0, 0.0],
                [50.0, -2.0, 0.0, 0.0], [100.0, 100.0, 0.0, 0.0]]
    state = make_state(pursuers, [EVADER])
    assert terms(state)["boundary"].tolist() == [-5.0, 0.0, -5.0, -5.0, -5.0, 0.0]


# ---------------------------------------------------------------- completion
def test_even_ring_of_three_gets_full_completion():
    # 120 (2 pi / 3) exp(-0) = 251.33 each
    state = make_state(ring(EVADER[:2], 6.0, [0, 120, 240]) + [[50.0, 80.0, 0.0, 0.0]], [EVADER])
    got = terms(state)["completion"]
    assert got.tolist() == pytest.approx([120 * 2 * math.pi / 3] * 3 + [0.0])


def test_completion_divides_by_ring_size_not_ring_size_minus_one():
    # even ring of four: 120 (2 pi / 4) = 188.5 (the published code's n_k - 1 would give 251.3)
    state = make_state(ring(EVADER[:2], 6.0, [0, 90, 180, 270]), [EVADER])
    assert terms(state)["completion"].tolist() == pytest.approx([120 * 2 * math.pi / 4] * 4)


def test_uneven_ring_completion_decays_with_gap_std():
    # gaps 100, 120, 140 deg: sigma = sqrt(800/3) deg = 0.2850 rad -> 120 (2pi/3) exp(-0.2850) = 188.98
    sigma = math.radians(math.sqrt(800.0 / 3.0))
    state = make_state(ring(EVADER[:2], 6.0, [0, 100, 220]), [EVADER])
    assert terms(state)["completion"].tolist() == pytest.approx([120 * 2 * math.pi / 3 * math.exp(-sigma)] * 3)


# ---------------------------------------------------------------- in the world
def test_world_reward_is_the_sum_of_its_terms_and_zero_after_collision():
    # pursuers 0 and 1 drive head-on from 2.5 m and collide in step 1; in step 2 they get nothing
    scenario = initial_scenario(
        pursuers=[[30.0, 30.0, 0.0, 2.0], [32.5, 30.0, math.pi, 2.0], far_row(0), far_row(1), far_row(2)],
        evaders=[[70.0, 30.0, 0.0, 0.0]],
    )
    world = World(scenario, evader_policy=ConstantEvader(7))
    world.reset()
    idle = np.full((1, 5), PURSUER_IDLE)
    _, first = world.step(idle)
    np.testing.assert_allclose(first.reward, first.reward_terms.sum(-1))
    assert first.reward_terms[0, :2, 1].tolist() == [-80.0, -80.0]
    assert first.acted[0].all()
    _, second = world.step(idle)
    assert second.acted[0].tolist() == [False, False, True, True, True]
    assert second.reward[0, :2].tolist() == [0.0, 0.0]
    assert np.all(second.reward_terms[0, :2] == 0.0)
    assert np.all(second.reward_terms[0, 2:, 0] == -1.0)


# ---------------------------------------------------------------- against a plain loop
def reference_terms(state, recipients, collided, ring_size, gap_std, p, arena) -> np.ndarray:
    """[B, N, 7] reward terms straight from world.md section 9 (pursuer_active after collisions,
    evader_active at the step start)."""
    num_envs, n = recipients.shape
    m = state.evader_active.shape[1]
    out = np.zeros((num_envs, n, 7))
    for b in range(num_envs):
        pxy, exy, oxy = state.pursuer_xy[b], state.evader_xy[b], state.obstacle_xy[b]
        p_on, e_on = state.pursuer_active[b], state.evader_active[b]

        def dist(u, v):
            return float(np.hypot(*(u - v)))

        crowd = [[i for i in range(n) if p_on[i] and dist(pxy[i], exy[j]) <= p.related_distance] if e_on[j] else []
                 for j in range(m)]
        counts = [len(crowd[j]) for j in range(m) if e_on[j]]
        imbalance = any(c < 3 for c in counts) and any(c > 5 for c in counts)
        for i in range(n):
            if not recipients[b, i]:
                continue
            emergency = (
                any(k != i and p_on[k] and dist(pxy[i], pxy[k]) < p.d_safe for k in range(n))
                or any(e_on[j] and dist(pxy[i], exy[j]) < p.d_safe for j in range(m))
                or any(dist(pxy[i], o) < p.d_safe and dist(pxy[i], o) <= p.perception_radius + r
                       for o, r in zip(oxy, state.obstacle_r[b]))
            )
            guidance = 0.0
            cooperation = -10.0 if imbalance else 0.0
            for j in range(m):
                if not e_on[j]:
                    continue
                d_e = dist(pxy[i], exy[j])
                guidance += 5.0 if d_e <= p.d_encircle else 5.0 * math.exp(-0.05 * (d_e - p.d_encircle))
                if i in crowd[j]:
                    count = len(crowd[j])
                    if 3 <= count < 5:
                        cooperation += 5.0 * max(0.0, 1.0 - 0.3 * (count - 3))
                    elif count >= 5:
                        cooperation -= 10.0
            x, y = pxy[i]
            outside = x < 0 or x > arena[0] or y < 0 or y > arena[1]
            size = ring_size[b, i]
            completion = 120.0 * (2 * math.pi / size) * math.exp(-gap_std[b, i]) if size else 0.0
            out[b, i] = [-1.0, -80.0 if collided[b, i] else 0.0, -5.0 if emergency else 0.0, guidance,
                         cooperation, -5.0 if outside else 0.0, completion]
    return out


@pytest.mark.parametrize("seed", [0, 1])
def test_reward_terms_match_plain_loop_on_random_worlds(seed):
    rng = np.random.default_rng(seed)
    state = random_state(rng, num_envs=20, num_pursuers=12, num_evaders=3, num_obstacles=6, low=-3.0, high=23.0,
                         active_fraction=0.9)
    recipients = state.pursuer_active.copy()
    collided = recipients & (rng.random(recipients.shape) < 0.15)
    state.pursuer_active = recipients & ~collided
    geometry = geometry_of(state)
    remember_perceived(state, geometry, DEFAULT, recipients)
    ring_ = encircle(state, geometry, DEFAULT, recipients)
    got, _ = paper_reward_terms(state.pursuer_xy, recipients, state.pursuer_active, collided, state.evader_active,
                                state.obstacle_r, geometry, ring_, DEFAULT, (20.0, 20.0))
    expected = reference_terms(state, recipients, collided, ring_.ring_size, ring_.gap_std, DEFAULT, (20.0, 20.0))
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-9)
    # the worlds exercise every term
    assert np.all((expected != 0).any(axis=(0, 1)))
