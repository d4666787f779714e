"""How well a network's Q-values predict the returns that follow them.

Greedy episodes of one scenario: at every step of every active pursuer, the network's
Q-value of the action it takes against the discounted return that follows, of the rewards
the learner is taught under the network's own config (`training.acting.taught_step`:
shaping, collision value, scale, what ends a transition). A Q-value far above the returns that
follow, or uncorrelated with them, is a value function that has not caught up with its
reward (docs/training-mattered.md, 7: neither the target copies nor the values' level
explained the drift there; with kappa = 1 the loss passes only the signs of the errors).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from terl_rt.sim.rollout import Rollout
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.world import World
from training.acting import explore, taught_step
from training.buffer import trim_padding
from training.config import Config
from training.networks import QNetwork
from training.torch_policy import as_tensors


MIN_CORRELATION = 0.5
"""Correlation of Q(s, a) with the return at which values track the returns."""
MAX_GAP_SHARE = 0.1
"""Largest mean |Q - return|, as a share of the returns' range, at which values track the returns."""


@dataclass(frozen=True)
class ValueCheck:
    """Q-values against the returns that follow, over every pursuer-step of the episodes."""

    scenario: str
    episodes: int
    pursuer_steps: int
    epsilon: float
    """probability of a random action per pursuer-step (0: greedy episodes)."""
    q_mean: float
    """mean Q(s, a) of the actions taken, in the taught return's units (times DataConfig.reward_scale)."""
    return_mean: float
    """mean discounted return that followed them (episodes cut at the step limit end there)."""
    gap_mean: float
    """mean of Q(s, a) minus the return: > 0 overestimates."""
    gap_median: float
    abs_gap_mean: float
    """mean |Q(s, a) - return|."""
    return_range: float
    """the returns' range, max - min over the pursuer-steps."""
    correlation: float | None
    """Pearson correlation of Q(s, a) and the return over the pursuer-steps (None when either is constant)."""

    @property
    def tracks_returns(self) -> bool:
        """The learner issue's bar for values that are values: correlation at least
        `MIN_CORRELATION` and mean |Q - return| under `MAX_GAP_SHARE` of the returns' range."""
        return (
            self.correlation is not None
            and self.correlation >= MIN_CORRELATION
            and self.abs_gap_mean < MAX_GAP_SHARE * self.return_range
        )


def value_check(
    model: QNetwork, config: Config, scenario: Scenario, episodes: int, seed: int, epsilon: float = 0.0
) -> ValueCheck:
    """Run `episodes` episodes of `scenario` as one batch (worlds seeded from `seed`, each kept to
    its first episode), greedy or, with `epsilon`, each pursuer's action replaced by a uniformly
    random one with that probability (as training explores; drawn from a generator seeded with
    `seed`), and compare each pursuer-step's Q(s, a) with its return."""
    rollout = Rollout(World(scenario, num_envs=episodes, seed=seed))
    rng = np.random.default_rng(seed)
    num_pursuers = scenario.pursuers
    potential = np.zeros(episodes * num_pursuers)
    ended = np.zeros(episodes, bool)
    steps: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []  # rows, Q(s, a), reward, terminal
    model.eval()
    while not ended.all():
        turn = rollout.turn()
        with torch.inference_mode():
            q_values = model.q_values(*as_tensors(trim_padding(turn.observation.rows(turn.rows).as_inputs()))).numpy()
        actions = explore(q_values.argmax(axis=1), epsilon, rng)
        step = rollout.step(actions)
        first = ~ended[turn.rows // num_pursuers]  # rows of worlds still in their first episode
        rows = turn.rows[first]
        rewards, terminal, _ = taught_step(step.result, rows, potential, config.data, config.learner.gamma)
        steps.append((rows, q_values[first, actions[first]], rewards, terminal))
        ended |= step.result.terminated | step.result.truncated
    following = np.zeros(episodes * num_pursuers)
    """[B * N] the discounted return from each row's next step on, built backwards."""
    q_taken, returns = [], []
    for rows, q, rewards, terminal in reversed(steps):
        following[rows] = rewards + config.learner.gamma * np.where(terminal, 0.0, following[rows])
        q_taken.append(q)
        returns.append(following[rows].copy())
    q_all, return_all = np.concatenate(q_taken), np.concatenate(returns)
    gaps = q_all - return_all
    return ValueCheck(
        scenario=scenario.name,
        episodes=episodes,
        epsilon=epsilon,
        pursuer_steps=len(q_all),
        q_mean=float(q_all.mean()),
        return_mean=float(return_all.mean()),
        gap_mean=float(gaps.mean()),
        gap_median=float(np.median(gaps)),
        abs_gap_mean=float(np.abs(gaps).mean()),
        return_range=float(return_all.max() - return_all.min()),
        correlation=float(np.corrcoef(q_all, return_all)[0, 1]) if q_all.std() and return_all.std() else None,
    )
