"""Replay memory of per-pursuer transitions.

One row is one pursuer's transition (s, a, R, s', done, discount): observations in the
contract layout (ego [4], teammates [P, 7], evaders [E, 7], obstacles [O, 5] float32,
mask [1 + P + E + O] bool), action uint8, R the taught reward float32, done bool,
discount = gamma (a column of its own, so replay files of every run read alike). Rows do not depend on how many pursuers a
scenario has, so curriculum stages share one buffer. A row takes about 1 KB with E = 8
(the observation is stored twice). The buffer saves to and loads from one .npz file
(plain arrays, no pickles).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import NamedTuple

import numpy as np

from terl_rt.files import atomic_output
from terl_rt.policy.contract import EGO_FEATURES, EVADER_FEATURES, INPUT_NAMES, OBSTACLE_FEATURES, TEAMMATE_FEATURES
from terl_rt.sim.actions import NUM_PURSUER_ACTIONS
from terl_rt.sim.observation import OBSTACLE_SLOTS, TEAMMATE_SLOTS


class ReplayBatch(NamedTuple):
    """Sampled transitions; every array has the batch as its first axis (rows R)."""

    observations: dict[str, np.ndarray]
    """ego [R, 4], teammates [R, P, 7], evaders [R, E, 7], obstacles [R, O, 5] float32, mask [R, L] bool."""
    actions: np.ndarray
    """[R] int64 pursuer action indices."""
    rewards: np.ndarray
    """[R] float32 taught rewards (terl_rt.sim.reward.taught_reward)."""
    next_observations: dict[str, np.ndarray]
    """like `observations`, a step later (before any reset)."""
    dones: np.ndarray
    """[R] float32: 1.0 where the pursuer's transition ends its episode (no bootstrap)."""
    discounts: np.ndarray
    """[R] float32: gamma, the discount of the bootstrapped value."""


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
        self.discounts = np.zeros(capacity, np.float32)
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
        discounts: np.ndarray,
    ) -> None:
        """Store R transitions: observation arrays [R, ...] (see `ReplayBatch`), actions [R]
        int in [0, 9), returns [R], dones [R] bool, discounts [R]. When R exceeds the
        capacity only the last `capacity` rows are kept."""
        actions = np.asarray(actions)
        rows = len(actions)
        for name, values in (("rewards", rewards), ("dones", dones), ("discounts", discounts)):
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
        self.discounts[index] = np.asarray(discounts)[keep]
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
            discounts=self.discounts[index],
        )

    # --- persistence
    def save(self, path: str | Path) -> None:
        """Write the filled rows, oldest first, to `path` (.npz, through a temporary name)."""
        order = (self.position - self.size + np.arange(self.size)) % self.capacity
        arrays = {"evader_slots": np.array(self.shapes["evaders"][0])}
        for key in INPUT_NAMES:
            arrays[f"obs_{key}"] = self.observations[key][order]
            arrays[f"next_{key}"] = self.next_observations[key][order]
        for name in ("actions", "rewards", "dones", "discounts"):
            arrays[name] = getattr(self, name)[order]
        with atomic_output(path, replace=True) as temporary, open(temporary, "wb") as handle:
            np.savez(handle, **arrays)  # a handle: savez adds no .npz to it

    def load(self, path: str | Path) -> None:
        """Replace the contents with the rows saved at `path` (the newest `capacity` of them).

        Raises ValueError when the file's layout does not match this buffer's."""
        with np.load(path, allow_pickle=False) as data:
            slots = int(data["evader_slots"])
            if slots != self.shapes["evaders"][0]:
                raise ValueError(f"{path}: saved with {slots} evader slots, this buffer has {self.shapes['evaders'][0]}")
            self.position = self.size = 0
            self.add(
                {key: data[f"obs_{key}"] for key in INPUT_NAMES}, data["actions"], data["rewards"],
                {key: data[f"next_{key}"] for key in INPUT_NAMES}, data["dones"], data["discounts"],
            )


def pad_evader_slots(inputs: Mapping[str, np.ndarray], evader_slots: int) -> dict[str, np.ndarray]:
    """Observation arrays [R, ...] (contract layout) with their E evader slots widened to
    `evader_slots` >= E: the added slots are empty (zero tokens, mask False), as a world fills
    slots it has no evader for, so a network's output does not change. Scenarios with fewer
    evader slots then share a buffer with larger ones (Config.mixed_scenarios)."""
    evaders = inputs["evaders"]
    rows, slots = evaders.shape[:2]
    if slots == evader_slots:
        return dict(inputs)
    if slots > evader_slots:
        raise ValueError(f"pad_evader_slots: the inputs have {slots} evader slots, more than {evader_slots}")
    extra = evader_slots - slots
    mask = inputs["mask"]
    end = mask.shape[1] - inputs["obstacles"].shape[1]  # mask columns: ego, teammates, evaders | obstacles
    return {
        **inputs,
        "evaders": np.concatenate([evaders, np.zeros((rows, extra) + evaders.shape[2:], evaders.dtype)], axis=1),
        "mask": np.concatenate([mask[:, :end], np.zeros((rows, extra), bool), mask[:, end:]], axis=1),
    }


def trim_padding(inputs: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Observation arrays [R, ...] (contract layout) with each entity group's slots (teammates,
    evaders, obstacles) cut after the last slot that is valid in any row, keeping at least one.

    Only slots empty in every row go, and every operation of the networks is masked, so their
    outputs are those of the full arrays up to float round-off: a batch from a buffer padded to
    20 evader slots, or a stage with 3 pursuers and 5 teammate slots, costs what its entities
    cost. The arrays come back as views where nothing is cut (the mask is always a new array).
    """
    mask = inputs["mask"]
    start, kept_columns, trimmed = 1, [np.arange(1)], dict(inputs)
    for name in ("teammates", "evaders", "obstacles"):
        slots = inputs[name].shape[1]
        valid = np.flatnonzero(mask[:, start : start + slots].any(axis=0))  # slots valid in some row
        keep = int(valid[-1]) + 1 if len(valid) else 1
        trimmed[name] = inputs[name][:, :keep]
        kept_columns.append(np.arange(start, start + keep))
        start += slots
    trimmed["mask"] = mask[:, np.concatenate(kept_columns)]
    return trimmed
