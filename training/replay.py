"""Replay memory of per-pursuer transitions, in preallocated NumPy arrays.

One row is one active pursuer's transition (s, a, r, s', done): observations in the
contract layout (ego [4], teammates [P, 7], evaders [E, 7], obstacles [O, 5] float32,
mask [1 + P + E + O] bool), action uint8, reward float32, done bool. Rows do not
depend on how many pursuers a scenario has, so curriculum stages share one buffer.
A row takes about 1 KB with E = 8 (the observation is stored twice).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

import numpy as np

from terl_rt.policy.contract import EGO_FEATURES, EVADER_FEATURES, OBSTACLE_FEATURES, TEAMMATE_FEATURES
from terl_rt.sim.actions import NUM_PURSUER_ACTIONS
from terl_rt.sim.observation import OBSTACLE_SLOTS, TEAMMATE_SLOTS
from training.export import INPUT_NAMES


class ReplayBatch(NamedTuple):
    """Sampled transitions; every array has the batch as its first axis (rows R)."""

    observations: dict[str, np.ndarray]
    """ego [R, 4], teammates [R, P, 7], evaders [R, E, 7], obstacles [R, O, 5] float32, mask [R, L] bool."""
    actions: np.ndarray
    """[R] int64 pursuer action indices."""
    rewards: np.ndarray
    """[R] float32 rewards of the step."""
    next_observations: dict[str, np.ndarray]
    """like `observations`, after the step (before any reset)."""
    dones: np.ndarray
    """[R] float32: 1.0 where the pursuer's transition ends its episode (no bootstrap)."""


class ReplayBuffer:
    """A ring buffer of `capacity` pursuer transitions; the oldest rows are overwritten first."""

    def __init__(
        self,
        capacity: int,
        evader_slots: int,
        teammate_slots: int = TEAMMATE_SLOTS,
        obstacle_slots: int = OBSTACLE_SLOTS,
    ) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self.capacity = capacity
        self.shapes = {
            "ego": (EGO_FEATURES,),
            "teammates": (teammate_slots, TEAMMATE_FEATURES),
            "evaders": (evader_slots, EVADER_FEATURES),
            "obstacles": (obstacle_slots, OBSTACLE_FEATURES),
            "mask": (1 + teammate_slots + evader_slots + obstacle_slots,),
        }
        """Per-row shape of each observation array."""
        # np.zeros maps pages lazily: memory is used as rows are written, not up front.
        self.observations = {key: self._allocate(key) for key in INPUT_NAMES}
        self.next_observations = {key: self._allocate(key) for key in INPUT_NAMES}
        self.actions = np.zeros(capacity, np.uint8)
        self.rewards = np.zeros(capacity, np.float32)
        self.dones = np.zeros(capacity, np.bool_)
        self.position = 0
        """Row the next transition is written to."""
        self.size = 0
        """Rows holding transitions, at most `capacity`."""

    def _allocate(self, key: str) -> np.ndarray:
        dtype = np.bool_ if key == "mask" else np.float32
        return np.zeros((self.capacity,) + self.shapes[key], dtype)

    def __len__(self) -> int:
        return self.size

    def add(
        self,
        observations: Mapping[str, np.ndarray],
        actions: np.ndarray,
        rewards: np.ndarray,
        next_observations: Mapping[str, np.ndarray],
        dones: np.ndarray,
    ) -> None:
        """Store R transitions: observation arrays [R, ...] (see `ReplayBatch`), actions [R]
        int in [0, 9), rewards [R], dones [R] bool. When R exceeds the capacity only the
        last `capacity` rows are kept."""
        actions = np.asarray(actions)
        rows = len(actions)
        for name, values in (("rewards", rewards), ("dones", dones)):
            if np.shape(values) != (rows,):
                raise ValueError(f"add: {name} must have shape ({rows},), got {np.shape(values)}")
        for group in (observations, next_observations):
            for key in INPUT_NAMES:
                expected = (rows,) + self.shapes[key]
                if np.shape(group[key]) != expected:
                    raise ValueError(f"add: {key} must have shape {expected}, got {np.shape(group[key])}")
        if rows and (actions.min() < 0 or actions.max() >= NUM_PURSUER_ACTIONS):
            raise ValueError(f"add: actions must lie in [0, {NUM_PURSUER_ACTIONS}), got {actions.tolist()}")

        keep = slice(max(0, rows - self.capacity), rows)
        kept = rows - keep.start
        index = (self.position + np.arange(kept)) % self.capacity
        for key in INPUT_NAMES:
            self.observations[key][index] = observations[key][keep]
            self.next_observations[key][index] = next_observations[key][keep]
        self.actions[index] = actions[keep]
        self.rewards[index] = np.asarray(rewards)[keep]
        self.dones[index] = np.asarray(dones)[keep]
        self.position = (self.position + kept) % self.capacity
        self.size = min(self.size + kept, self.capacity)

    def sample(self, batch_size: int, rng: np.random.Generator) -> ReplayBatch:
        """`batch_size` transitions drawn uniformly with replacement by `rng`."""
        if self.size == 0:
            raise ValueError("sample: the replay buffer is empty")
        index = rng.integers(0, self.size, batch_size)
        return ReplayBatch(
            observations={key: self.observations[key][index] for key in INPUT_NAMES},
            actions=self.actions[index].astype(np.int64),
            rewards=self.rewards[index],
            next_observations={key: self.next_observations[key][index] for key in INPUT_NAMES},
            dones=self.dones[index].astype(np.float32),
        )
