"""Evaluations kept as they finish, so that a long comparison that is cut off goes on where it
stopped.

`terl-rt report` over several policies evaluates every policy on every scenario, hours at 50
episodes a preset for a grid's 18 policies. Each (policy, scenario) result is written here, one
JSON file of its episodes, the moment it is done; the same command run again reads it back
instead of running those episodes again. That is sound because an evaluation is determined
by what the key holds: the policy file's bytes (sha256), the scenario (its whole JSON form,
step limit included), the episodes and the seed (episode k of seed s is
`Simulator(scenario, seed=s + k)`, whatever the batching, workers or backend).
A file that cannot be read back as such a result is set aside with a warning and the
evaluation runs again.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
from pathlib import Path

from terl_rt.evaluation.episodes import ScenarioResult, scenario_result
from terl_rt.files import atomic_output
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.scenario import Scenario

logger = logging.getLogger(__name__)

SAVED_SCHEMA = 1
"""Version of the saved files' fields: a file of another version is not read."""

_METRIC_FIELDS = (frozenset(EpisodeMetrics(False, 0, 0.0, 0.0, 0, 0).to_dict()),
                  frozenset(EpisodeMetrics(False, 0, 0.0, 0.0, 0, 0, None, None, None, 0, 0, 0).to_dict()))
"""The fields a saved episode has: a comparison's episodes run greedy, without the shield's
counts; those saved since terl-rt recorded what collisions touched have its counts too."""


class SavedResults:
    """A folder of finished evaluations, one JSON file each, named by the hash of its key."""

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = Path(folder)

    @staticmethod
    def key(policy_sha256: str, scenario: Scenario, episodes: int, seed: int) -> dict:
        """What determines an evaluation's episodes, as JSON (lists where the scenario has tuples,
        as a file reads back)."""
        return json.loads(json.dumps({"schema": SAVED_SCHEMA, "policy_sha256": policy_sha256,
                                      "scenario": scenario.to_dict(), "episodes": episodes, "seed": seed}))

    def path(self, key: dict) -> Path:
        digest = hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:32]
        return self.folder / f"{digest}.json"

    def load(self, policy_sha256: str, scenario: Scenario, episodes: int, seed: int) -> ScenarioResult | None:
        """The saved result of this evaluation (`scenario` with its step limit in force), or
        None where none is saved or the file cannot be read back (a warning says which)."""
        key = self.key(policy_sha256, scenario, episodes, seed)
        path = self.path(key)
        if not path.exists():
            return None
        try:
            data = json.loads(path.read_text())
            if data["key"] != key:
                raise ValueError("it holds another evaluation")
            rows = data["per_episode"]
            if len(rows) != episodes or any(set(row) not in _METRIC_FIELDS for row in rows):
                raise ValueError(f"expected {episodes} episodes of the fields {sorted(_METRIC_FIELDS[-1])}")
            per_episode = [EpisodeMetrics(**row) for row in rows]
            return scenario_result(scenario, seed, per_episode, float(data["wall_s"]))
        except (OSError, ValueError, KeyError, TypeError) as error:
            logger.warning("%s is no saved evaluation of %s (%s): evaluating again", path, scenario.name, error)
            return None

    def save(self, policy_sha256: str, scenario: Scenario, result: ScenarioResult) -> Path:
        """Write `result` (of `scenario`, its step limit in force) whole or not at all
        (`terl_rt.files.atomic_output`)."""
        key = self.key(policy_sha256, scenario, result.episodes, result.seed)
        path = self.path(key)
        self.folder.mkdir(parents=True, exist_ok=True)
        text = json.dumps({"key": key, "scenario": scenario.name, "wall_s": result.wall_s,
                           "per_episode": [metrics.to_dict() for metrics in result.per_episode]})
        with atomic_output(path, replace=True) as staging:
            staging.write_text(text)
        return path

    def count(self) -> int:
        """Saved evaluations in the folder (not the hidden temporary file of one being written)."""
        if not self.folder.is_dir():
            return 0
        return sum(not path.name.startswith(".") for path in self.folder.glob("*.json"))

    def remove(self) -> None:
        """Delete the folder and what it holds (once the outputs they fed are written)."""
        shutil.rmtree(self.folder, ignore_errors=True)
