"""Risk-aware acting from a distributional (IQN) head: act on the conditional value at risk
CVaR_alpha of each action's return, the mean of its lowest alpha share of quantiles, instead
of on the mean of all of them (the Q-values).

The quantiles are the contract's optional output `quantiles` [B, K, 9] at the fixed
fractions tau_k = (k + 0.5) / K, K = 32 (docs/policy.md section 3); returns are the
training reward's units (no unit of time or length).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

RISK_MEASURES = ("cvar",)
"""The names `Risk.parse` reads before the colon."""


@dataclass(frozen=True)
class Risk:
    """CVaR_alpha: the mean of the lowest `alpha` share of each action's quantiles."""

    alpha: float
    """share of the quantiles kept, in (0, 1]: 1 is the mean of all of them (the Q-values up
    to float rounding); 0.25 the lowest 8 of the contract's 32."""

    def __post_init__(self) -> None:
        alpha = self.alpha
        if isinstance(alpha, bool) or not isinstance(alpha, (int, float)) or not 0 < alpha <= 1:
            raise ValueError(f"risk: cvar's ALPHA must be a number in (0, 1], got {alpha!r:.40}")

    @classmethod
    def parse(cls, text: str) -> Risk:
        """`cvar:ALPHA` (e.g. cvar:0.25) as a Risk; ValueError in one line for anything else."""
        measure, _, value = str(text).partition(":")
        if measure.strip().lower() not in RISK_MEASURES or not value:
            raise ValueError(f"risk: expected cvar:ALPHA with ALPHA in (0, 1] (e.g. cvar:0.25), got {text!r:.40}")
        try:
            alpha = float(value)
        except ValueError:
            raise ValueError(f"risk: cvar's ALPHA must be a number in (0, 1], got {value!r:.40}") from None
        return cls(alpha if math.isfinite(alpha) else -1.0)

    def kept(self, fractions: int) -> int:
        """The quantiles kept of `fractions` (K, 32 in the contract): round(alpha K), at least 1."""
        return max(1, round(self.alpha * fractions))

    @property
    def label(self) -> str:
        """`cvar:ALPHA`, as `parse` reads it and results name the rule."""
        return f"cvar:{self.alpha:g}"

    def values(self, quantiles: np.ndarray) -> np.ndarray:
        """[..., 9] float32 CVaR of each action from its quantiles [..., K, 9]: the mean of the
        `kept(K)` lowest. Sorted first, so that quantiles that cross (an IQN head does not force
        them to rise with tau) still give the lower tail; without crossing these are the
        quantiles at the lowest fractions."""
        lowest = np.sort(quantiles, axis=-2)[..., : self.kept(quantiles.shape[-2]), :]
        return lowest.mean(axis=-2, dtype=np.float64).astype(np.float32)
