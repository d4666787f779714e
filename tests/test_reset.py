"""Scenario generation at reset (world.md section 4): every placement rule, over many seeds."""

from __future__ import annotations

import itertools
import math
import time

import numpy as np
import pytest
from sim_helpers import initial_scenario

from terl_rt.sim.params import WorldParams
from terl_rt.sim.scenario import Scenario, ScenarioError
from terl_rt.sim.world import World

PRESETS = ("small-15", "medium-56", "large-80", "cc-28", "curriculum-1", "curriculum-3")
R0 = WorldParams().vortex_core_radius


def reset_states(scenario: Scenario, seeds=(0, 1, 2), num_envs: int = 8):
    """World states after reset, one per (seed, env)."""
    out = []
    for seed in seeds:
        world = World(scenario, num_envs=num_envs, seed=seed)
        world.reset()
        s = world.state
        for b in range(num_envs):
            out.append({name: getattr(s, name)[b] for name in (
                "pursuer_xy", "pursuer_theta", "pursuer_speed", "pursuer_active", "evader_xy", "evader_theta",
                "evader_speed", "evader_active", "obstacle_xy", "obstacle_r", "vortex_xy", "vortex_gamma",
                "vortex_clockwise")})
    return out


@pytest.fixture(scope="module", params=PRESETS)
def preset_resets(request):
    scenario = Scenario.preset(request.param)
    return scenario, reset_states(scenario)


def pair_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.hypot(*(a[:, None, :] - b[None, :, :]).transpose(2, 0, 1))


def test_counts_follow_the_scenario(preset_resets):
    scenario, states = preset_resets
    for s in states:
        assert s["pursuer_xy"].shape == (scenario.pursuers, 2)
        assert s["evader_xy"].shape == (scenario.evaders, 2)
        assert s["obstacle_xy"].shape == (scenario.obstacles, 2)
        assert s["vortex_xy"].shape == (scenario.vortices, 2)
        assert s["pursuer_active"].all() and s["evader_active"].all()


def test_evaders_start_inside_their_margin_and_apart(preset_resets):
    scenario, states = preset_resets
    width, height = scenario.arena
    for s in states:
        x, y = s["evader_xy"].T
        assert np.all((x >= 15) & (x <= width - 15) & (y >= 15) & (y <= height - 15))
        d = pair_distances(s["evader_xy"], s["evader_xy"])
        assert np.all(d[~np.eye(len(d), dtype=bool)] > scenario.clear_r)


def test_pursuers_start_inside_their_margin_apart_and_away_from_evaders(preset_resets):
    scenario, states = preset_resets
    width, height = scenario.arena
    for s in states:
        x, y = s["pursuer_xy"].T
        assert np.all((x >= 2) & (x <= width - 2) & (y >= 2) & (y <= height - 2))
        d = pair_distances(s["pursuer_xy"], s["pursuer_xy"])
        assert np.all(d[~np.eye(len(d), dtype=bool)] > scenario.clear_r)
        assert np.all(pair_distances(s["pursuer_xy"], s["evader_xy"]) > scenario.min_pursuer_evader_init_dis)


def test_vortex_cores_lie_inside_the_arena_clear_of_robots(preset_resets):
    scenario, states = preset_resets
    width, height = scenario.arena
    for s in states:
        x, y = s["vortex_xy"].T
        assert np.all((x - R0 >= 0) & (x + R0 <= width) & (y - R0 >= 0) & (y + R0 <= height))
        robots = np.concatenate([s["pursuer_xy"], s["evader_xy"]])
        assert np.all(pair_distances(s["vortex_xy"], robots) >= R0 + scenario.clear_r)


def test_vortex_circulation_comes_from_edge_speed_range(preset_resets):
    # Gamma = 2 pi * 0.25 * v_e with v_e in [2.5, 5.0]
    _, states = preset_resets
    for s in states:
        assert np.all((s["vortex_gamma"] >= 2 * math.pi * 0.25 * 2.5) & (s["vortex_gamma"] <= 2 * math.pi * 0.25 * 5.0))


def test_vortex_pairs_respect_the_spacing_rules(preset_resets):
    _, states = preset_resets
    for s in states:
        xy, gamma, cw = s["vortex_xy"], s["vortex_gamma"], s["vortex_clockwise"]
        for i, j in itertools.combinations(range(len(gamma)), 2):
            dist = float(np.hypot(*(xy[i] - xy[j])))
            if cw[i] == cw[j]:
                # same direction: dist >= (Gamma_i + Gamma_j) / (2 pi v_rel_max), v_rel_max = 1
                assert dist >= (gamma[i] + gamma[j]) / (2 * math.pi * 1.0)
            else:
                # opposite: Gamma_l / (2 pi (dist - 2 r0)) <= 0.8 Gamma_s / (2 pi r0)
                large, small = max(gamma[i], gamma[j]), min(gamma[i], gamma[j])
                assert dist > 2 * R0
                assert large / (2 * math.pi * (dist - 2 * R0)) <= 0.8 * small / (2 * math.pi * R0)


def test_obstacles_respect_their_placement_rules(preset_resets):
    scenario, states = preset_resets
    width, height = scenario.arena
    for s in states:
        (x, y), r = s["obstacle_xy"].T, s["obstacle_r"]
        assert np.all((x >= 5) & (x <= width - 5) & (y >= 5) & (y <= height - 5))
        assert np.all((r >= 1.0) & (r <= 1.1))
        assert np.all((x - r >= 0) & (x + r <= width) & (y - r >= 0) & (y + r <= height))
        robots = np.concatenate([s["pursuer_xy"], s["evader_xy"]])
        assert np.all(pair_distances(s["obstacle_xy"], robots) >= r[:, None] + scenario.clear_r)
        assert np.all(pair_distances(s["obstacle_xy"], s["vortex_xy"]) > R0 + r[:, None] + 5)
        d = pair_distances(s["obstacle_xy"], s["obstacle_xy"])
        off = ~np.eye(len(r), dtype=bool)
        assert np.all(d[off] > (r[:, None] + r[None, :] + 5)[off])


def test_headings_and_speeds_lie_in_their_ranges(preset_resets):
    _, states = preset_resets
    for s in states:
        for theta in (s["pursuer_theta"], s["evader_theta"]):
            assert np.all((theta >= 0) & (theta < 2 * math.pi))
        assert np.all((s["pursuer_speed"] >= 0) & (s["pursuer_speed"] <= 3.0))
        assert np.all((s["evader_speed"] >= 0) & (s["evader_speed"] <= 3.5))


def test_headings_speeds_and_directions_are_spread():
    states = reset_states(Scenario.preset("small-19"), seeds=(0,), num_envs=10)
    theta = np.concatenate([s["pursuer_theta"] for s in states])
    speed = np.concatenate([s["evader_speed"] for s in states])
    clockwise = np.concatenate([s["vortex_clockwise"] for s in states])
    assert theta.min() < 0.5 and theta.max() > 2 * math.pi - 0.5
    assert speed.min() < 0.5 and speed.max() > 3.0
    assert 0.25 < clockwise.mean() < 0.75


def test_rectangular_arena_bounds_each_axis():
    scenario = Scenario(name="wide", arena=(200.0, 80.0), pursuers=8, evaders=2, obstacles=3, vortices=3)
    for s in reset_states(scenario, seeds=(0, 1), num_envs=5):
        for group, margin in (("evader_xy", 15.0), ("pursuer_xy", 2.0), ("obstacle_xy", 5.0)):
            x, y = s[group].T
            assert np.all((x >= margin) & (x <= 200.0 - margin)), group
            assert np.all((y >= margin) & (y <= 80.0 - margin)), group


# ---------------------------------------------------------------- placement failures
@pytest.mark.parametrize(
    ("field", "changes"),
    [
        ("evaders", {"evaders": 100}),
        ("pursuers", {"pursuers": 300}),
        ("pursuers", {"min_pursuer_evader_init_dis": 1000.0}),
        ("vortices", {"params": WorldParams(vortex_core_radius=100.0)}),
        ("obstacles", {"obstacles": 500}),
    ],
)
def test_unplaceable_counts_raise_scenario_error_naming_the_field(field, changes):
    scenario = Scenario.preset("small-15").replace(**changes)
    start = time.perf_counter()
    with pytest.raises(ScenarioError, match=rf"^{field}:"):
        World(scenario).reset()
    assert time.perf_counter() - start < 10.0


def test_arena_too_small_for_the_spawn_margin_raises_scenario_error():
    # evaders start in [15, W - 15]: a 20 m arena leaves no room, refused before any reset.
    with pytest.raises(ScenarioError, match=r"arena.*evader_spawn_margin"):
        Scenario(name="tiny", arena=(20.0, 20.0), pursuers=3, evaders=1, obstacles=0, vortices=0,
                 clear_r=0.0, min_pursuer_evader_init_dis=0.0)


# ---------------------------------------------------------------- explicit initial states
def explicit():
    return initial_scenario(
        pursuers=[[10.0, 10.0, 0.5, 1.0], [30.0, 10.0, 7.0, 2.0], [50.0, 10.0, 6.0, 3.0]],
        evaders=[[60.0, 60.0, 1.5, 3.5]],
        obstacles=[[90.0, 90.0, 1.05]],
        vortices=[[30.0, 80.0, 3.0, 1.0], [80.0, 30.0, 4.0, 0.0]],
    )


def test_initial_state_is_reproduced_exactly():
    scenario = explicit()
    world = World(scenario, num_envs=2, seed=3)
    world.reset()
    init, s = scenario.initial_state, world.state
    for b in range(2):
        assert np.array_equal(s.pursuer_xy[b], init.pursuers[:, :2])
        assert np.array_equal(s.pursuer_speed[b], init.pursuers[:, 3])
        assert np.array_equal(s.evader_xy[b], init.evaders[:, :2])
        assert np.array_equal(s.evader_theta[b], init.evaders[:, 2])
        assert np.array_equal(s.obstacle_xy[b], init.obstacles[:, :2])
        assert np.array_equal(s.obstacle_r[b], init.obstacles[:, 2])
        assert np.array_equal(s.vortex_xy[b], init.vortices[:, :2])
        assert np.array_equal(s.vortex_gamma[b], init.vortices[:, 2])
        assert s.vortex_clockwise[b].tolist() == [True, False]
    assert s.pursuer_theta[0, :2].tolist() == [0.5, 7.0 - 2 * math.pi]  # headings kept in [0, 2pi)


def test_initial_state_draws_nothing():
    # different seeds, repeated resets: always the same world
    scenario = explicit()
    first = World(scenario, seed=1)
    first.reset()
    other = World(scenario, seed=2)
    other.reset()
    snapshot = first.state.copy()
    first.reset()
    for s in (other.state, first.state):
        for name in ("pursuer_xy", "pursuer_theta", "pursuer_speed", "pursuer_vel", "evader_xy", "evader_vel",
                     "obstacle_xy", "vortex_xy", "vortex_gamma"):
            assert np.array_equal(getattr(s, name), getattr(snapshot, name)), name
