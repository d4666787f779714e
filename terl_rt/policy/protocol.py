"""What an evaluation runs: the `Policy` protocol, which `OnnxPolicy`, training's torch
policy and a user's own function (through `CallablePolicy`) all meet.

A policy takes the observation rows of every deciding pursuer at once (an `Observation`
with leading shape [R], one row a pursuer, world.md section 8) and gives a `PolicyOutput`:
the greedy actions [R] (indices into the 9 pursuer actions) and, where it has them, the
outputs an episode log keeps (target weights [R, E]) and the Q-values [R, 9].
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from terl_rt.policy.onnx_policy import PolicyOutput
from terl_rt.sim.actions import NUM_PURSUER_ACTIONS
from terl_rt.sim.observation import Observation


@runtime_checkable
class Policy(Protocol):
    """Observations in, actions (and what a log keeps) out."""

    @property
    def name(self) -> str:
        """What results and logs call the policy (an ONNX file's `terl.model`)."""

    @property
    def path(self) -> Path:
        """Where it came from, as error messages name it (a file, or `<name>` without one)."""

    def evaluate(self, observation: Observation) -> PolicyOutput:
        """Greedy actions [R] int64, target weights [R, E] float32 or None and Q-values
        [R, 9] float32 or None, for the R rows of `observation`."""


class CallablePolicy:
    """A function of observations to actions as a `Policy`: `act(observation)` gets the
    observation rows [R] of the deciding pursuers and returns R action indices in [0, 9)."""

    def __init__(self, act: Callable[[Observation], Any], name: str | None = None) -> None:
        self.act = act
        self._name: str = name or str(getattr(act, "__name__", type(act).__name__))

    def __repr__(self) -> str:
        return f"CallablePolicy({self.act!r}, name={self._name!r})"

    @property
    def name(self) -> str:
        """The name given, else the function's `__name__`."""
        return self._name

    @property
    def path(self) -> Path:
        """`<name>`: a function has no file."""
        return Path(f"<{self._name}>")

    def evaluate(self, observation: Observation) -> PolicyOutput:
        """The function's actions for the R rows of `observation`, checked: R integers in
        [0, 9) (ValueError naming the policy otherwise); no Q-values or target weights."""
        rows = observation.ego.shape[0]
        actions = np.asarray(self.act(observation))
        if actions.shape != (rows,) or actions.dtype.kind not in "iu":
            raise ValueError(f"policy {self._name} returned {actions.dtype} {list(actions.shape)} for {rows} "
                             f"observation rows; expected {rows} integer action indices")
        if rows and (actions.min() < 0 or actions.max() >= NUM_PURSUER_ACTIONS):
            raise ValueError(f"policy {self._name} returned actions in [{actions.min()}, {actions.max()}]; "
                             f"expected indices in [0, {NUM_PURSUER_ACTIONS})")
        return PolicyOutput(q_values=None, target_weights=None, actions=actions.astype(np.int64))


def as_policy(policy: Policy | Callable[[Observation], Any]) -> Policy:
    """`policy` itself when it meets `Policy`, a plain function wrapped in `CallablePolicy`;
    TypeError for anything else."""
    if isinstance(policy, Policy):
        return policy
    if callable(policy):
        return CallablePolicy(policy)
    raise TypeError(f"expected a policy (a path, a shipped policy's name, a Policy or a function of "
                    f"observations to actions), got {type(policy).__name__}")
