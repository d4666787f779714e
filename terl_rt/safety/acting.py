"""How a policy's outputs become actions: greedy on the Q-values (the contract's rule), or
risk-aware on the CVaR of the quantiles (`terl_rt.safety.risk`), each optionally under the
shield (`terl_rt.safety.shield`). One `Acting` travels with every episode of a run
(terl_rt.evaluation.runs.EpisodeSpec), so workers and Ray tasks act as this process does.

    acting = Acting(shield=Shield(), risk=Risk(0.25))
    output = acting.act(policy, observation, scenario.params)  # output.actions, output.overridden
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from terl_rt.safety.risk import Risk
from terl_rt.safety.shield import Shield, shield_actions
from terl_rt.sim.observation import Observation
from terl_rt.sim.params import WorldParams

if TYPE_CHECKING:  # the policy layer sits above this one: its output's type is named, not imported
    from terl_rt.policy.onnx_policy import PolicyOutput


@dataclass(frozen=True)
class Acting:
    """The acting rule of a run: a shield, a risk measure, both, or neither (the policy's
    greedy actions as they are)."""

    shield: Shield | None = None
    risk: Risk | None = None

    @classmethod
    def of(cls, shield: Shield | bool | None = None, risk: Risk | str | None = None) -> Acting:
        """From the library's arguments: shield True (the default Shield), a Shield, or
        False / None; risk a Risk, "cvar:ALPHA" or None. ValueError in one line otherwise."""
        if shield is True:
            shield = Shield()
        elif shield is False:
            shield = None
        if shield is not None and not isinstance(shield, Shield):
            raise ValueError(f"shield must be True, False, None or a Shield, got {type(shield).__name__}")
        if isinstance(risk, str):
            risk = Risk.parse(risk)
        if risk is not None and not isinstance(risk, Risk):
            raise ValueError(f"risk must be None, a Risk or 'cvar:ALPHA', got {type(risk).__name__}")
        return cls(shield, risk)

    @property
    def plain(self) -> bool:
        """Neither shield nor risk: the policy's own greedy actions."""
        return self.shield is None and self.risk is None

    @property
    def label(self) -> str:
        """What a results row adds to the policy's name: "" when plain, else e.g.
        "shield 0.5 m / 4 steps, cvar:0.25"."""
        return ", ".join(part.label for part in (self.shield, self.risk) if part is not None)

    def to_dict(self) -> dict[str, Any]:
        """The rule in results JSON: {"shield": its parameters or None, "risk": "cvar:ALPHA" or None}."""
        return {"shield": None if self.shield is None else self.shield.to_dict(),
                "risk": None if self.risk is None else self.risk.label}

    def check(self, policy: Any) -> None:
        """ValueError in one line when the rule cannot act with `policy`: risk-aware acting
        needs the optional output quantiles (contract revision 1.1)."""
        if self.risk is not None and not getattr(policy, "has_quantiles", False):
            raise ValueError(
                f"risk-aware acting ({self.risk.label}): policy {policy.name} ({policy.path}) has no quantiles output; "
                "re-export it (contract revision 1.1, docs/policy.md) or act on its mean"
            )

    def act(self, policy: Any, observation: Observation, params: WorldParams) -> PolicyOutput:
        """The policy's outputs for the R rows of `observation` (leading shape [R]) with the
        rule's actions [R] (and `overridden` [R] bool under the shield). A plain rule returns
        `policy.evaluate(observation)` itself."""
        if self.plain:
            return policy.evaluate(observation)
        output = policy.evaluate(observation, quantiles=True) if self.risk is not None else policy.evaluate(observation)
        preference, actions = output.q_values, output.actions
        if self.risk is not None:
            preference = self.risk.values(output.quantiles)
            actions = np.argmax(preference, axis=-1).astype(np.int64)
        overridden = None
        if self.shield is not None:
            actions, overridden = shield_actions(observation, actions, preference, params, self.shield)
        return dataclasses.replace(output, actions=actions, overridden=overridden)
