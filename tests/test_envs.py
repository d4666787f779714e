"""terl_rt.envs: the world as a PettingZoo ParallelEnv, checked by PettingZoo's own tests."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pettingzoo")

from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test  # noqa: E402
from pettingzoo.utils.conversions import parallel_to_aec  # noqa: E402

from terl_rt import Scenario, Simulator  # noqa: E402
from terl_rt.envs import env as aec_env  # noqa: E402
from terl_rt.envs import parallel_env, raw_env, state_size  # noqa: E402
from terl_rt.sim.state import LOGGED_FIELDS  # noqa: E402
from terl_rt.sim.reward import REWARD_TERMS  # noqa: E402

SHORT = Scenario.preset("small-11").replace(max_steps=40)


def test_pettingzoo_parallel_api_test():
    parallel_api_test(parallel_env(SHORT, seed=0), num_cycles=100)


def test_pettingzoo_parallel_seed_test():
    parallel_seed_test(lambda: parallel_env(SHORT), num_cycles=50)


# api_test advises Box or Discrete observations; ours are a Dict of the ONNX contract's groups.
AEC_ADVICE = pytest.mark.filterwarnings("ignore:Observation:UserWarning")


@AEC_ADVICE
def test_pettingzoo_api_test_through_parallel_to_aec():
    api_test(parallel_to_aec(parallel_env(SHORT, seed=0)), num_cycles=20)


@AEC_ADVICE
def test_env_and_raw_env_are_the_aec_forms_as_in_pettingzoo_s_own_envs():
    api_test(aec_env(scenario=SHORT, seed=0), num_cycles=20)
    raw = raw_env(scenario=SHORT, seed=0)
    raw.reset(seed=0)
    assert raw.agents == parallel_env(SHORT).possible_agents


def test_state_is_one_float32_vector_in_state_space():
    env = parallel_env(SHORT, seed=0)
    env.reset(seed=0)
    state = env.state()
    assert env.state_space.contains(state)
    # small-11: 11 pursuers, 3 evaders, 2 obstacles, 4 vortices; x, y pairs count twice.
    n, m, o, v = SHORT.pursuers, SHORT.evaders, SHORT.obstacles, SHORT.vortices
    assert state.shape == (state_size(SHORT),) == (n * 7 + m * 7 + o * 3 + v * 4 + 1,)
    named = env.world_state()
    np.testing.assert_array_equal(state[: 2 * n], named["pursuer_xy"].ravel().astype(np.float32))
    assert state[-1] == named["step"] == 0
    assert list(named) == [f.key for f in LOGGED_FIELDS] + ["pursuer_collided"]


def test_no_seed_draws_fresh_entropy_as_the_simulator_does():
    first = [parallel_env(SHORT).reset()[0]["pursuer_0"]["ego"] for _ in range(2)]
    assert not np.array_equal(*first)
    sims = [Simulator(SHORT, seed=None).reset().ego[0] for _ in range(2)]
    assert not np.array_equal(*sims)


def test_a_generator_seed_gives_the_episode_of_the_int_it_draws():
    env = parallel_env(SHORT)
    observations, _ = env.reset(seed=np.random.default_rng(5))
    drawn = int(np.random.default_rng(5).integers(2**63))
    np.testing.assert_array_equal(observations["pursuer_3"]["evaders"], Simulator(SHORT, seed=drawn).reset().evaders[3])


@pytest.mark.parametrize("seed", [1.5, "7", True])
def test_a_seed_that_is_not_an_int_or_a_generator_is_refused_by_name(seed):
    with pytest.raises(TypeError, match=r"seed must be an int >= 0, a np.random.Generator or None, got"):
        parallel_env(SHORT).reset(seed=seed)


@pytest.mark.parametrize("actions", [None, [0, 1], 4], ids=["none", "list", "int"])
def test_step_without_a_dict_of_actions_is_a_type_error_naming_it(actions):
    env = parallel_env(SHORT)
    env.reset(seed=0)
    with pytest.raises(TypeError, match=r"step: actions must be a dict of agent name -> action index, got"):
        env.step(actions)


def test_agents_and_spaces_follow_the_contract():
    env = parallel_env("small-15", seed=3)
    assert env.possible_agents == [f"pursuer_{i}" for i in range(15)]
    space = env.observation_space("pursuer_0")
    assert space["ego"].shape == (4,) and space["teammates"].shape == (5, 7)
    assert space["evaders"].shape == (8, 7) and space["obstacles"].shape == (5, 5)
    assert space["mask"].n == 1 + 5 + 8 + 5
    assert env.action_space("pursuer_4").n == 9
    observations, infos = env.reset(seed=3)
    assert set(observations) == set(infos) == set(env.agents)
    for agent, obs in observations.items():
        assert space.contains(obs), agent
        assert obs["ego"].dtype == np.float32 and obs["mask"].dtype == bool


def test_an_episode_is_the_simulators_episode():
    """The wrapper adds no rules: same seed and actions give the Simulator's rewards."""
    env = parallel_env(SHORT)
    sim = Simulator(SHORT, seed=7)
    observations, _ = env.reset(seed=7)
    first = sim.reset(seed=7)
    np.testing.assert_array_equal(observations["pursuer_2"]["evaders"], first.evaders[2])
    rng = np.random.default_rng(1)
    while env.agents:
        actions = rng.integers(0, 9, SHORT.pursuers)
        live = list(env.agents)
        _, rewards, terminations, truncations, infos = env.step({a: actions[int(a.split("_")[1])] for a in live})
        _, info = sim.step(actions)
        for agent in live:
            i = int(agent.split("_")[1])
            assert rewards[agent] == info.reward[i]
            assert set(infos[agent]["reward_terms"]) == set(REWARD_TERMS)
            assert terminations[agent] == (info.terminated or bool(info.collided[i]))
            assert truncations[agent] == (info.truncated and not terminations[agent])
    assert sim.done
    assert env.metrics() == sim.metrics()


def test_collided_pursuers_are_terminated_and_leave_the_agents():
    # Every pursuer holding action 7 for 150 steps: several of them collide (seed 0).
    scenario = Scenario.preset("small-19").replace(max_steps=150)
    env = parallel_env(scenario, seed=0)
    env.reset(seed=0)
    seen_collision = False
    while env.agents:
        live = list(env.agents)
        _, _, terminations, truncations, infos = env.step({agent: 7 for agent in live})
        for agent in live:
            if infos[agent]["collided"]:
                seen_collision = True
                assert terminations[agent] and agent not in env.agents
        assert all(not (terminations[a] or truncations[a]) for a in env.agents)
    assert seen_collision


def test_the_step_limit_truncates():
    env = parallel_env(Scenario.preset("small-11").replace(max_steps=3), seed=0)
    env.reset(seed=0)
    for _ in range(3):
        _, _, terminations, truncations, infos = env.step({agent: 4 for agent in env.agents})
    assert env.agents == []
    assert any(truncations.values())
    assert all(terminations[a] or truncations[a] for a in truncations)
    assert "metrics" in next(iter(infos.values()))


def test_render_returns_an_rgb_frame():
    env = parallel_env(SHORT, seed=0, render_mode="rgb_array", render_size=256)
    env.reset(seed=0)
    env.step({agent: 1 for agent in env.agents})
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3 and frame.shape[1] == 256
    assert parallel_env(SHORT).render() is None


def test_the_onnx_policy_plugs_in_as_the_readme_shows():
    from pathlib import Path

    from terl_rt.policy.onnx_policy import OnnxPolicy

    policy = OnnxPolicy(Path(__file__).parents[1] / "exported" / "terl.onnx")
    env = parallel_env(SHORT)
    observations, _ = env.reset(seed=1)
    while env.agents:
        batch = {key: np.stack([observations[a][key] for a in env.agents]) for key in observations[env.agents[0]]}
        actions = policy.act(batch)
        observations, *_ = env.step(dict(zip(env.agents, actions.tolist())))
    assert env.metrics().steps > 0
