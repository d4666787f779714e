"""The paper's claims (policy.md section 4), each a criterion checked on measured means.

A claim is a list of `Comparison`s between `Measure`s (one method's mean of one metric over
one report group, with its 95 % interval) or against a bound. `check_claims` checks every
claim of `CLAIMS` on measured rows and on the paper's own tables: the verdict is the means'
answer, and `ClaimCheck.clear` says whether the intervals give it too.
`terl_rt.paper.comparison` checks them on one policy a method,
`terl_rt.paper.seed_comparison` on the means over seeds.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass

from terl_rt.evaluation.stats import format_interval
from terl_rt.paper.numbers import ABLATION_TABLE, BASELINES, CC_TABLE, SCALE_GROUPS, SMALL_RELEASED, TERL

REPRODUCES = "reproduces"
DOES_NOT_REPRODUCE = "does not reproduce"
NOT_MEASURED = "not measured"
FIG3_METHODS: tuple[str, ...] = (TERL, *BASELINES)
"""The methods of the paper's Fig. 3: TERL and its baselines."""


@dataclass(frozen=True)
class Measure:
    """One method's mean of one metric over one group's presets."""

    label: str
    """'IQN large' (method and group)."""
    metric: str
    """'success_rate', 'travel_time_s' or 'collision_ratio' (CI_METRICS)."""
    value: float
    """success rate and collision ratio in [0, 1], travel time in s."""
    ci95: tuple[float, float] | None
    """its 95 % interval; None for the paper's numbers."""

    def shown(self) -> str:
        """'IQN large success 0.65 [0.45, 0.85]'."""
        word, digits, unit = _SHOWN[self.metric]
        interval = "" if self.ci95 is None else " " + format_interval(self.ci95, digits)
        return f"{self.label} {word} {self.value:.{digits}f}{unit}{interval}"


_SHOWN = {
    "success_rate": ("success", 2, ""), "travel_time_s": ("time", 1, " s"), "collision_ratio": ("collisions", 3, ""),
}
"""metric -> (its word in a claim's measured figures, decimals, unit)."""
_TOLERANCE = 1e-9
_OPERATORS: dict[str, Callable[[float, float], bool]] = {
    ">": operator.gt,
    "<": operator.lt,
    ">=": lambda a, b: a >= b - _TOLERANCE,
    "<=": lambda a, b: a <= b + _TOLERANCE,
}


@dataclass(frozen=True)
class Comparison:
    """`left op right`: a measured figure against another or against a bound."""

    left: Measure
    op: str
    """'>', '<', '>=' or '<='."""
    right: Measure | float

    def holds(self) -> bool:
        """True when the means (or the mean and the bound) satisfy the comparison."""
        right = self.right.value if isinstance(self.right, Measure) else self.right
        return _OPERATORS[self.op](self.left.value, right)

    def clear(self) -> bool | None:
        """True when the 95 % intervals give the means' answer too: every value of the left
        interval against every value of the right one (or the bound) satisfies the
        comparison when the means do, and fails it when they fail it. None when an
        interval is unknown."""
        left = self.left.ci95
        right = self.right.ci95 if isinstance(self.right, Measure) else (self.right, self.right)
        if left is None or right is None or any(math.isnan(v) for v in (*left, *right)):
            return None
        upward = self.op in (">", ">=")
        if self.holds():
            return _OPERATORS[self.op](left[0], right[1]) if upward else _OPERATORS[self.op](left[1], right[0])
        # Failed: the opposite comparison must hold between the intervals' far ends.
        return not (_OPERATORS[self.op](left[1], right[0]) if upward else _OPERATORS[self.op](left[0], right[1]))


class _Measures:
    """Looks measures up by (method, group, metric) and notes the ones missing."""

    def __init__(self, rows: Mapping[tuple[str, str], tuple[Mapping[str, float], Mapping | None]]):
        self.rows = rows
        """(method, group) -> (metric -> value, metric -> 95 % interval or None)."""
        self.missing: list[str] = []

    def get(self, method: str, group: str, metric: str) -> Measure:
        label = f"{method} {group}"
        if (method, group) not in self.rows:
            if label not in self.missing:
                self.missing.append(label)
            return Measure(label, metric, math.nan, None)
        values, intervals = self.rows[(method, group)]
        return Measure(label, metric, values[metric], None if intervals is None else tuple(intervals[metric]))


@dataclass(frozen=True)
class Claim:
    """A claim of the paper, the criterion it is checked by and that criterion's comparisons."""

    claim: str
    criterion: str
    comparisons: Callable[[_Measures], list[Comparison]]


def _success(measures: _Measures, method: str, group: str) -> Measure:
    return measures.get(method, group, "success_rate")


def _claims() -> tuple[Claim, ...]:
    """policy.md section 4's claims, each with a simple criterion on the group means."""
    claims = [
        Claim(
            "At small scale every method succeeds in over 95 % of episodes"
            + (" (released config)" if group == SMALL_RELEASED else ""),
            "success rate > 0.95 for each of TERL, IQN, DQN and MEAN at small scale"
            + (" (released config)" if group == SMALL_RELEASED else ""),
            lambda f, group=group: [Comparison(_success(f, m, group), ">", 0.95) for m in FIG3_METHODS],
        )
        for group in ("small", SMALL_RELEASED)
    ]
    claims.append(Claim(
        "TERL keeps 100 % success at medium and large scale",
        "TERL's success rate = 1.00 at medium and at large scale",
        lambda f: [Comparison(_success(f, TERL, group), ">=", 1.0) for group in ("medium", "large")],
    ))
    claims += [
        Claim(
            f"{method} degrades with scale",
            f"{method}'s success rate at large scale < at small scale",
            lambda f, method=method: [Comparison(_success(f, method, "large"), "<", _success(f, method, "small"))],
        )
        for method in ("IQN", "DQN")
    ]
    claims.append(Claim(
        "MEAN does worst",
        "MEAN's success rate < each of TERL's, IQN's and DQN's, at medium and at large scale",
        lambda f: [
            Comparison(_success(f, "MEAN", group), "<", _success(f, other, group))
            for group in ("medium", "large") for other in (TERL, "IQN", "DQN")
        ],
    ))
    claims.append(Claim(
        "Every baseline fails CC, with about 0.9 of its pursuers collided",
        "on CC, success rate = 0.00 and collision ratio >= 0.80 for each of IQN, DQN and MEAN",
        lambda f: [
            comparison
            for method in BASELINES
            for comparison in (
                Comparison(_success(f, method, "CC"), "<=", 0.0),
                Comparison(f.get(method, "CC", "collision_ratio"), ">=", 0.80),
            )
        ],
    ))
    for method, part in (("w/o RE", "relation extraction"), ("w/o TS", "target selection")):
        claims.append(Claim(
            f"Removing {part} costs success on CC",
            f"{method}'s success rate on CC < TERL's",
            lambda f, method=method: [Comparison(_success(f, method, "CC"), "<", _success(f, TERL, "CC"))],
        ))
    for method, part in (("w/o RE", "relation extraction"), ("w/o TS", "target selection")):
        claims.append(Claim(
            f"Removing {part} costs travel time at every scale",
            f"{method}'s travel time > TERL's at small, medium and large scale and on CC",
            lambda f, method=method: [
                Comparison(f.get(method, group, "travel_time_s"), ">", f.get(TERL, group, "travel_time_s"))
                for group in SCALE_GROUPS
            ],
        ))
    return tuple(claims)


CLAIMS: tuple[Claim, ...] = _claims()
"""The claims `claim_checks` checks, in the order of policy.md section 4."""


@dataclass(frozen=True)
class ClaimCheck:
    """One claim checked on the measured group means."""

    claim: str
    criterion: str
    measured: str
    """the figures compared, with their 95 % intervals; or what was not evaluated."""
    verdict: str
    """'reproduces' (every comparison of the criterion holds), 'does not reproduce' or
    'not measured' (a method or group it needs was not evaluated)."""
    clear: bool | None
    """the 95 % intervals give the verdict too, so it is clear of the episodes' noise:
    every comparison holds between them (reproduces), or one fails between them (does not
    reproduce). None when not measured or an interval it needs is unknown."""
    in_paper: str
    """the same criterion on the paper's own tables: 'holds', 'does not hold', or 'not in
    its tables' (numbers the paper gives only in its Fig. 3)."""

    def to_dict(self) -> dict:
        return asdict(self)


MeasuredRows = Mapping[tuple[str, str], tuple[Mapping[str, float], Mapping[str, tuple[float, float]]]]
"""(method, report group) -> (metric -> measured value, metric -> its 95 % interval), by the
names success_rate, travel_time_s (s) and collision_ratio."""


def check_claims(measured_rows: MeasuredRows) -> list[ClaimCheck]:
    """Check every claim of CLAIMS on `measured_rows` and on the paper's own tables."""
    paper_rows = _paper_rows()
    checks = []
    for claim in CLAIMS:
        measures = _Measures(measured_rows)
        comparisons = claim.comparisons(measures)
        paper = _Measures(paper_rows)
        paper_comparisons = claim.comparisons(paper)
        in_paper = ("not in its tables" if paper.missing
                    else "holds" if all(c.holds() for c in paper_comparisons) else "does not hold")
        if measures.missing:
            checks.append(ClaimCheck(claim.claim, claim.criterion, f"not evaluated: {', '.join(measures.missing)}",
                                     NOT_MEASURED, None, in_paper))
            continue
        shown = []
        for comparison in comparisons:
            for measure in (comparison.left, comparison.right):
                if isinstance(measure, Measure) and measure.shown() not in shown:
                    shown.append(measure.shown())
        reproduces = all(c.holds() for c in comparisons)
        # Reproduced: every comparison must be clear; not reproduced: one clear failure is enough.
        clear = [c.clear() for c in comparisons if reproduces or not c.holds()]
        if reproduces:
            verdict_clear = None if None in clear else all(clear)
        else:
            verdict_clear = True if True in clear else None if None in clear else False
        checks.append(ClaimCheck(
            claim.claim, claim.criterion, "; ".join(shown),
            REPRODUCES if reproduces else DOES_NOT_REPRODUCE, verdict_clear, in_paper,
        ))
    return checks


def _paper_rows() -> dict[tuple[str, str], tuple[dict[str, float], None]]:
    """The paper's tables as (method, group) -> (metric -> value, None): the ablation table,
    and the CC comparison for the baselines (TERL on CC: the ablation's row, the one set
    against w/o RE and w/o TS)."""
    rows = {(method, group): row for (group, method), row in ABLATION_TABLE.items()}
    rows.update({(method, "CC"): row for method, row in CC_TABLE.items() if method != TERL})
    return {key: (claim_metrics(row.success_rate, row.travel_time_s, row.collision_ratio), None) for key, row in rows.items()}


def claim_metrics(success_rate: float, travel_time_s: float, collision_ratio: float) -> dict[str, float]:
    """The three means by their CI_METRICS names."""
    return {"success_rate": success_rate, "travel_time_s": travel_time_s, "collision_ratio": collision_ratio}
