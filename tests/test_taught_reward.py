"""The reward a learner is taught (terl_rt.sim.reward.taught_reward), on cases worked by hand:
potential shaping of the income, the value a collision ends on, the scale."""

from __future__ import annotations

import numpy as np
import pytest

from terl_rt.sim.reward import REWARD_TERMS, taught_reward

NO = np.array([False])
YES = np.array([True])


def pursuer_terms(time=-1.0, guidance=0.0, cooperation=0.0, completion=0.0) -> np.ndarray:
    """One pursuer's reward terms [1, len(REWARD_TERMS)]."""
    terms = np.zeros((1, len(REWARD_TERMS)))
    for name, value in (("time", time), ("guidance", guidance), ("cooperation", cooperation), ("completion", completion)):
        terms[0, REWARD_TERMS.index(name)] = value
    return terms


def test_unshaped_unscaled_the_taught_reward_is_the_sum_of_the_terms():
    terms = pursuer_terms(guidance=4.0, cooperation=-10.0, completion=150.0)  # -1 + 4 - 10 + 150
    reward, potential = taught_reward(terms, NO, NO, np.zeros(1), 0.99)
    assert reward.tolist() == [143.0] and potential.tolist() == [0.0]


def test_holding_an_open_ring_earns_only_the_potential_rent():
    # guidance 5 + cooperation 5 every step: unshaped +9 a step; shaped (k = 1, gamma 0.9)
    # the first step pays gamma * 10 - 0 - 1 = 8, later ones 0.9 * 10 - 10 - 1 = -2.
    potential, rewards = np.zeros(1), []
    for _ in range(3):
        reward, potential = taught_reward(pursuer_terms(guidance=5.0, cooperation=5.0), NO, NO, potential, 0.9, shaping=1.0)
        rewards.append(float(reward[0]))
    assert rewards == pytest.approx([8.0, -2.0, -2.0])


def test_shaping_keeps_the_crowding_penalty_and_zeroes_the_terminal_potential():
    # crowding (cooperation -10) stays a per-step cost; a terminal step gets no gamma * Phi(s')
    # and gives back Phi(s) = 2 * 4 = 8; completion is paid as it is.
    terms = pursuer_terms(guidance=4.0, cooperation=-10.0, completion=150.0)
    reward, potential = taught_reward(terms, NO, YES, np.array([8.0]), 0.99, shaping=2.0)
    assert reward.tolist() == pytest.approx([-1.0 - 10.0 + 150.0 - 8.0]) and potential.tolist() == [8.0]


def test_shaped_discounted_return_differs_from_the_unshaped_by_the_start_potential_only():
    # Ng et al.: sum_t gamma^t F_t telescopes to gamma^T Phi(s_T) - Phi(s_0) = 0 for an episode that
    # ends terminal with Phi(s_0) = 0: the shaped return is the unshaped return of the other terms.
    rng = np.random.default_rng(3)
    gamma, steps = 0.97, 12
    terms = [pursuer_terms(guidance=g, cooperation=c, completion=120.0 * (t == steps - 1))
             for t, (g, c) in enumerate(zip(rng.uniform(0, 5, steps), rng.uniform(-10, 5, steps)))]
    potential, shaped, base = np.zeros(1), 0.0, 0.0
    for t, step_terms in enumerate(terms):
        reward, potential = taught_reward(step_terms, NO, np.array([t == steps - 1]), potential, gamma, shaping=3.0)
        shaped += gamma**t * reward[0]
        income = step_terms[0, REWARD_TERMS.index("guidance")] + max(step_terms[0, REWARD_TERMS.index("cooperation")], 0.0)
        base += gamma**t * (step_terms.sum() - income)
    assert shaped == pytest.approx(base)


def test_a_collision_ends_on_the_collision_value_discounted_once():
    # two pursuers, the first collides: -1 + 0.9 * -100 = -91; the second keeps -1
    terms = np.concatenate([pursuer_terms(), pursuer_terms()])
    collided = np.array([True, False])
    reward, _ = taught_reward(terms, collided, collided, np.zeros(2), 0.9, collision_value=-100.0)
    assert reward.tolist() == pytest.approx([-91.0, -1.0])


def test_the_scale_multiplies_everything_the_collision_value_included():
    terms = np.concatenate([pursuer_terms(guidance=3.0), pursuer_terms()])
    collided = np.array([True, False])
    plain, _ = taught_reward(terms, collided, collided, np.zeros(2), 0.9, collision_value=-100.0)
    scaled, _ = taught_reward(terms, collided, collided, np.zeros(2), 0.9, scale=0.05, collision_value=-100.0)
    assert scaled == pytest.approx(0.05 * plain)
