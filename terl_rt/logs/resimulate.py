"""Re-simulate a logged episode from its scenario (its evader included), seed and actions,
bit for bit (`terl-rt replay --verify`).

The simulator is deterministic (same scenario, seed and actions give the same episode),
so every /state of a log must come out of the simulator again exactly: float64 fields
are compared by their bits, not within a tolerance. The evaders' recorded actions and
the episode's end are checked too.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from terl_rt.logs.format import EpisodeLogError
from terl_rt.logs.reader import EpisodeLogReader, LoggedStep
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.scenario import scenario_label
from terl_rt.sim.simulator import Simulator
from terl_rt.sim.state import LOGGED_FIELDS
from terl_rt.sim.world import WORLD_VERSION


@dataclass(frozen=True)
class Mismatch:
    """The first difference between a log and the re-simulation."""

    step: int
    field: str
    """a /state field, "evader_actions", "done", "metrics", or "log" (the step does not
    read back: a damaged chunk)."""
    detail: str


@dataclass(frozen=True)
class VerifyReport:
    """Outcome of `verify` for one episode."""

    path: Path
    episode: int
    scenario: str
    seed: int
    evader: str
    """the evaders' behaviour the episode was re-simulated with (`Scenario.evader`)."""
    steps_checked: int
    """logged steps compared (after the reset frame)."""
    complete: bool
    """the logged episode reached its end (False: cut off, checked as far as it goes)."""
    mismatch: Mismatch | None

    @property
    def ok(self) -> bool:
        return self.mismatch is None

    def format(self) -> str:
        """One line, e.g. "episode 0 (small-11, seed 0): ok, 57 steps bit-identical" (the scenario
        "small-11/still" with another evader than the paper's)."""
        head = f"episode {self.episode} ({scenario_label(self.scenario, self.evader)}, seed {self.seed})"
        if self.mismatch is not None:
            m = self.mismatch
            return f"{head}: MISMATCH at step {m.step}, {m.field}: {m.detail}"
        tail = "" if self.complete else " (the log stops there: the episode was cut off)"
        return f"{head}: ok, {self.steps_checked} steps bit-identical{tail}"

    def to_dict(self) -> dict:
        return {
            "episode": self.episode, "scenario": self.scenario, "evader": self.evader, "seed": self.seed,
            "steps_checked": self.steps_checked, "complete": self.complete, "ok": self.ok,
            "mismatch": None if self.mismatch is None else {
                "step": self.mismatch.step, "field": self.mismatch.field, "detail": self.mismatch.detail,
            },
        }


def _first_difference(recorded: np.ndarray, simulated: np.ndarray) -> str | None:
    """None when the arrays are identical bit for bit, else where and how they differ."""
    simulated = np.asarray(simulated)
    if recorded.shape != simulated.shape:
        return f"shape {recorded.shape} recorded, {simulated.shape} simulated"
    if recorded.dtype == simulated.dtype == np.float64:
        differs = recorded.view(np.uint64) != simulated.view(np.uint64)  # -0.0 vs 0.0 and NaNs count too
    else:
        differs = recorded != simulated
    if not differs.any():
        return None
    where = tuple(int(i) for i in np.argwhere(differs)[0])
    label = f"[{', '.join(map(str, where))}]" if where else ""
    a, b = recorded[where], simulated[where]
    return f"{label} recorded {a!r}, simulated {b!r}"


def _compare_state(step: LoggedStep, simulated: dict[str, np.ndarray]) -> Mismatch | None:
    recorded = step.state
    for f in LOGGED_FIELDS:
        problem = _first_difference(np.asarray(recorded[f.key]), np.asarray(simulated[f.key]))
        if problem is not None:
            return Mismatch(step.step, f.key, problem)
    return None


def _comparable(simulated: EpisodeMetrics, recorded: EpisodeMetrics) -> EpisodeMetrics:
    """`simulated` as a log recorded it: without the return where the log has none (logs
    written before terl-rt recorded returns), with the shield's counts of the log (they
    come from the acting rule, not the world; the actions they led to are what is checked)."""
    if recorded.team_return is None:
        simulated = dataclasses.replace(simulated, team_return=None)
    return dataclasses.replace(simulated, shield_overrides=recorded.shield_overrides, decisions=recorded.decisions)


def verify(path: str | os.PathLike, episode: int = 0) -> VerifyReport:
    """Re-simulate episode `episode` (file order) of the log at `path` and compare every
    recorded state with the simulator's, bit for bit; the report names the first mismatch
    (a step that does not read back is one)."""
    reader = EpisodeLogReader(path)
    if reader.world_version != WORLD_VERSION:
        raise EpisodeLogError(
            f"{path}: recorded by a simulator of world version {reader.world_version}; this terl-rt simulates "
            f"world version {WORLD_VERSION}, so its episodes cannot be re-simulated bit for bit "
            f"(evaluate again to log them in this version)"
        )
    entry = reader.episode(episode)
    simulator = Simulator(entry.scenario, seed=entry.seed)  # with the evader the scenario names
    simulator.reset()
    mismatch: Mismatch | None = None
    checked = 0
    last_step = -1
    try:
        for step in reader.steps(episode):
            last_step = step.step
            if step.step > 0:
                if simulator.done:
                    mismatch = Mismatch(step.step, "done", "the log goes on after the simulated episode ended")
                    break
                _, info = simulator.step(step.pursuer_actions)
                problem = _first_difference(step.evader_actions, info.evader_actions)
                if problem is not None:
                    mismatch = Mismatch(step.step, "evader_actions", problem)
                    break
                checked += 1
            mismatch = _compare_state(step, simulator.state())
            if mismatch is not None:
                break
    except EpisodeLogError as error:  # a damaged chunk: the steps before it were compared
        mismatch = Mismatch(last_step + 1, "log", str(error))
    if mismatch is None and entry.complete:
        if not simulator.done:
            mismatch = Mismatch(last_step, "done", "the log ends here but the simulated episode goes on")
        elif _comparable(simulator.metrics(), entry.metrics) != entry.metrics:
            mismatch = Mismatch(
                last_step, "metrics", f"recorded {entry.metrics.to_dict()}, simulated {simulator.metrics().to_dict()}"
            )
    return VerifyReport(
        path=Path(path), episode=episode, scenario=entry.scenario.name, seed=entry.seed, evader=entry.scenario.evader,
        steps_checked=checked, complete=entry.complete, mismatch=mismatch,
    )
