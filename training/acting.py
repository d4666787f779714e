"""Acting and storing while training: epsilon-greedy actions from one batched forward of a
Q-network, and what each batch step of a group of worlds puts into the replay buffer.

Transitions: each pursuer's step is stored with the reward the learner is taught
(terl_rt.sim.reward.taught_reward under `DataConfig`: shaping, collision value, scale) and,
when `DataConfig.store_pursuers` is set, only a random subset of a world step's pursuers
enter the buffer. A pursuer's transition is terminal when it collides, and when its episode
terminates if `DataConfig.success_ends_transitions`; when it is truncated, if
`DataConfig.truncation_ends`. Acting takes the mean of the quantiles at the contract's fixed
fractions, or at random ones (`LearnerConfig.random_acting_fractions`).
"""

from __future__ import annotations

import numpy as np
import torch

from terl_rt.sim.actions import NUM_PURSUER_ACTIONS
from terl_rt.sim.observation import Observation
from terl_rt.sim.reward import REWARD_TERMS, taught_reward
from terl_rt.sim.rollout import Rollout
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.world import StepResult, World
from training.buffer import ReplayBuffer, pad_evader_slots, trim_padding
from training.config import DataConfig
from training.networks import QNetwork
from training.networks.encoders import NUM_FIXED_FRACTIONS
from training.torch_policy import as_tensors, network_device


# ---------------------------------------------------------------- acting
def greedy_actions(model: QNetwork, states: dict[str, np.ndarray], fractions: np.ndarray | None = None) -> np.ndarray:
    """argmax of the eval-mode Q-values of the states with their empty slots trimmed
    (`trim_padding`): [R] int64. Q-values are the mean of the quantiles at the fixed fractions,
    as the exported policy's, or at `fractions` [R, K] in [0, 1), a row's own."""
    if len(states["ego"]) == 0:
        return np.zeros(0, np.int64)
    model.eval()
    inputs = as_tensors(trim_padding(states), network_device(model))
    taus = None if fractions is None else torch.from_numpy(fractions).to(inputs[0].device)
    with torch.inference_mode():
        return model.q_values(*inputs, taus).argmax(dim=1).cpu().numpy()


def epsilon_greedy(
    model: QNetwork, states: dict[str, np.ndarray], epsilon: float, rng: np.random.Generator,
    random_fractions: bool = False,
) -> np.ndarray:
    """Action indices [R] for the rows' states [R, ...]: greedy in one batched forward,
    each row replaced by a uniformly random action with probability `epsilon`. With
    `random_fractions` each row's Q-values are its mean at NUM_FIXED_FRACTIONS fractions drawn
    from `rng` (LearnerConfig.random_acting_fractions), not at the fixed ones."""
    drawn = rng.random((len(states["ego"]), NUM_FIXED_FRACTIONS), dtype=np.float32) if random_fractions else None
    return explore(greedy_actions(model, states, drawn), epsilon, rng)


def explore(chosen: np.ndarray, epsilon: float, rng: np.random.Generator) -> np.ndarray:
    """The action indices `chosen` [R], each replaced in place by a uniformly random action
    with probability `epsilon`; returns them."""
    random = rng.random(len(chosen)) < epsilon
    chosen[random] = rng.integers(0, NUM_PURSUER_ACTIONS, int(random.sum()))
    return chosen


# ---------------------------------------------------------------- storing
class TransitionStore:
    """What goes from a batch step into the replay buffer: every acting pursuer row (b * N + i
    of the B worlds) with the reward it is taught, and the optional per-step subsample."""

    def __init__(self, buffer: ReplayBuffer, data: DataConfig, gamma: float, num_rows: int) -> None:
        self.buffer = buffer
        self.data = data
        self.gamma = gamma
        self.potential = np.zeros(num_rows)
        """[rows] Phi of the state each row's last step ended in (DataConfig.potential_shaping; 0 before an episode)."""

    def add(
        self,
        rows: np.ndarray,
        states: dict[str, np.ndarray],
        actions: np.ndarray,
        next_observation: Observation,
        result: StepResult,
        rng: np.random.Generator,
    ) -> int:
        """Add the step of every pursuer that acted (rows [R] b * N + n and their states [R, ...],
        actions [B, N]); returns the transitions stored. Observations with fewer evader slots
        than the buffer's are padded to them (`pad_evader_slots`)."""
        num_pursuers = result.collided.shape[1]
        slots = self.buffer.shapes["evaders"][0]
        rewards, terminal, _ = taught_step(result, rows, self.potential, self.data, self.gamma)
        keep = np.arange(len(rows))
        if self.data.store_pursuers:
            # at most store_pursuers transitions per world of this step, drawn at random
            keep = subsample_per_group(rows // num_pursuers, self.data.store_pursuers, rng)
        states = pad_evader_slots({key: value[keep] for key, value in states.items()}, slots)
        next_states = pad_evader_slots(next_observation.rows(rows[keep]).as_inputs(), slots)
        self.buffer.add(
            states, actions.ravel()[rows[keep]], rewards[keep].astype(np.float32), next_states, terminal[keep],
            np.full(len(keep), self.gamma, np.float32),
        )
        return len(keep)


def taught_step(
    result: StepResult, rows: np.ndarray, potential: np.ndarray, data: DataConfig, gamma: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the learner is taught about one step of the pursuer rows [R] (b * N + n) that acted.

    Returns their rewards [R] (terl_rt.sim.reward.taught_reward of the terms the world paid,
    under `data`'s shaping, collision value and scale), whether each transition is terminal [R]
    (the pursuer collided, or its episode terminated (all evaders encircled, or too few
    pursuers left) when `data.success_ends_transitions`, or truncated when `data.truncation_ends`;
    other transitions are bootstrapped) and whether each row's episode stops here [R]
    (terminated or truncated). potential [B * N]: Phi of the state each row's last step ended
    in, updated in place (0 where the episode stops).
    """
    ended = (result.terminated | result.truncated)[:, None]
    ends = (result.terminated & data.success_ends_transitions) | (result.truncated & data.truncation_ends)  # [B]
    terminal = result.collided | ends[:, None]
    stops = np.broadcast_to(ended, terminal.shape).ravel()[rows]
    terminal = terminal.ravel()[rows]
    terms = result.reward_terms.reshape(-1, len(REWARD_TERMS))[rows]
    rewards, next_potential = taught_reward(
        terms, result.collided.ravel()[rows], terminal, potential[rows], gamma,
        data.reward_scale, data.potential_shaping, data.collision_value,
    )
    potential[rows] = np.where(terminal | stops, 0.0, next_potential)
    return rewards, terminal, stops


class WorldGroup:
    """B worlds of one scenario under training: their rollout, the transition store of their
    pursuer rows, and the sums of the episodes under way."""

    def __init__(
        self, scenario: Scenario, num_envs: int, buffer: ReplayBuffer, data: DataConfig, gamma: float,
        rng: np.random.Generator,
    ) -> None:
        self.scenario = scenario
        self.rollout = Rollout(World(scenario, num_envs, seed=int(rng.integers(2**31))))
        self.transitions = TransitionStore(buffer, data, gamma, num_envs * scenario.pursuers)
        self.returns = np.zeros(num_envs)
        """[B] per-pursuer return of each world's episode so far (summed rewards / N)."""
        self.terms = np.zeros((num_envs, len(REWARD_TERMS)))
        """[B, terms] the same split by reward term."""
        self.team = np.zeros(num_envs)
        """[B] the team-wide share of the cooperation term in it (StepResult.team_cooperation)."""


def subsample_per_group(groups: np.ndarray, limit: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of at most `limit` items of each group (groups [K] ints), drawn at random, sorted."""
    order = rng.permutation(len(groups))
    shuffled = groups[order]
    by_group = np.argsort(shuffled, kind="stable")
    sorted_groups = shuffled[by_group]
    first = np.searchsorted(sorted_groups, sorted_groups, side="left")
    rank = np.arange(len(groups)) - first
    return np.sort(order[by_group[rank < limit]])
