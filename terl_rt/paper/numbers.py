"""The TERL paper's published results (policy.md section 4) as data, and the goals they set.

The paper gives one number per scale group, not per preset: small (11, 15, 19
pursuers), medium (48, 51, 56), large (72, 76, 80), and the CC scenario (28 pursuers,
14 evaders) alone; 20 episodes a scenario. Every row is (success rate, travel time in
s, collision ratio), as world.md section 10 defines them.

The authors' released small-scale evaluation config runs 7 / 11 / 15 pursuers, not the
table's 11 / 15 / 19 (policy.md section 2), so reports add it as a group of its own,
"small (released config)", measured against the paper's small-scale numbers.

The paper prints two different TERL rows for CC: 0.80 / 226.78 s / 0.03 in its CC
comparison and 1.00 / 194.05 s / 0.02 in its ablation. Both are kept; the goals use
the comparison row, the one set against the baselines.
"""

from __future__ import annotations

from dataclasses import dataclass

from terl_rt.policy.models import MODELS

TERL = "TERL"
"""The paper's name for its own method in every table."""

PAPER_METHODS: dict[str, str] = {name: model.label for name, model in MODELS.items()}
"""The paper's name of each model (the `terl.model` metadata, policy.md section 1), in its order
(terl_rt.policy.models)."""

BASELINES: tuple[str, ...] = ("IQN", "DQN", "MEAN")
"""The methods the paper compares TERL with (its Fig. 3 and CC table)."""

ABLATIONS: tuple[str, ...] = ("w/o RE", "w/o TS")
"""TERL without relation extraction and without target selection (its ablation table)."""

SCALE_GROUPS: tuple[str, ...] = ("small", "medium", "large", "CC")
"""The scale groups the paper reports, in its order."""

SMALL_RELEASED = "small (released config)"
"""The group of the released small-scale evaluation config (small-published-7, -11, -15)."""

REPORT_GROUPS: tuple[str, ...] = ("small", SMALL_RELEASED, "medium", "large", "CC")
"""The groups a report summarises: the paper's, with the released small config after small."""

PRESET_GROUPS: dict[str, str] = {
    "small-11": "small", "small-15": "small", "small-19": "small",
    "medium-48": "medium", "medium-51": "medium", "medium-56": "medium",
    "large-72": "large", "large-76": "large", "large-80": "large",
    "cc-28": "CC",
    "small-published-7": SMALL_RELEASED, "small-published-11": SMALL_RELEASED, "small-published-15": SMALL_RELEASED,
}
"""Report group of each evaluation preset (world.md section 11)."""


@dataclass(frozen=True)
class PaperResult:
    """One published row: means over 20 episodes a scenario."""

    success_rate: float
    """fraction of episodes with every evader encircled, in [0, 1]."""
    travel_time_s: float
    """s: mean episode duration (decision steps x 0.5 s)."""
    collision_ratio: float
    """mean of collided pursuers / pursuers, in [0, 1]."""


CC_TABLE: dict[str, PaperResult] = {
    "TERL": PaperResult(0.80, 226.78, 0.03),
    "IQN": PaperResult(0.00, 150.50, 0.93),
    "MEAN": PaperResult(0.00, 210.75, 0.92),
    "DQN": PaperResult(0.00, 252.45, 0.90),
}
"""method -> result on the CC scenario (28 pursuers, 14 evaders)."""

ABLATION_TABLE: dict[tuple[str, str], PaperResult] = {
    ("small", "TERL"): PaperResult(1.00, 45.98, 0.00),
    ("small", "w/o RE"): PaperResult(1.00, 36.39, 0.02),
    ("small", "w/o TS"): PaperResult(1.00, 52.98, 0.00),
    ("medium", "TERL"): PaperResult(1.00, 63.80, 0.01),
    ("medium", "w/o RE"): PaperResult(1.00, 81.48, 0.45),
    ("medium", "w/o TS"): PaperResult(1.00, 78.02, 0.03),
    ("large", "TERL"): PaperResult(1.00, 62.62, 0.03),
    ("large", "w/o RE"): PaperResult(0.75, 161.94, 0.75),
    ("large", "w/o TS"): PaperResult(1.00, 84.68, 0.04),
    ("CC", "TERL"): PaperResult(1.00, 194.05, 0.02),
    ("CC", "w/o RE"): PaperResult(0.05, 100.42, 0.91),
    ("CC", "w/o TS"): PaperResult(0.55, 390.60, 0.06),
}
"""(scale group, method) -> result; w/o RE: without relation extraction, w/o TS:
without target selection (policy.md section 1)."""

TERL_BY_GROUP: dict[str, PaperResult] = {
    "small": ABLATION_TABLE[("small", TERL)],
    "medium": ABLATION_TABLE[("medium", TERL)],
    "large": ABLATION_TABLE[("large", TERL)],
    "CC": CC_TABLE[TERL],
}
"""The paper's TERL row each scale group is measured against (CC: the comparison row)."""


@dataclass(frozen=True)
class Goal:
    """What matching the paper's TERL means for one scale group."""

    min_success_rate: float
    """success rate at or above this, in [0, 1]."""
    max_travel_time_s: float
    """s: mean travel time at or under this (the paper's, rounded up to the second)."""
    max_collision_ratio: float
    """mean collision ratio at or under this, in [0, 1]."""


GOALS: dict[str, Goal] = {
    "small": Goal(1.00, 46.0, 0.03),
    "medium": Goal(1.00, 64.0, 0.03),
    "large": Goal(1.00, 63.0, 0.03),
    "CC": Goal(0.80, 227.0, 0.03),
}
"""scale group -> goal: every episode a success at small, medium and large scale and
0.80 at CC, a collision ratio of at most 0.03, and the paper's travel times."""


def scale_group(scenario_name: str) -> str | None:
    """The report group of an evaluation preset (one of REPORT_GROUPS), or None for a
    scenario the paper does not report (curriculum stages, files)."""
    return PRESET_GROUPS.get(scenario_name)


def paper_group(group: str) -> str:
    """The paper's scale group whose numbers the report group `group` is measured against."""
    return "small" if group == SMALL_RELEASED else group
