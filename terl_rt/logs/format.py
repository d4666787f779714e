"""The MCAP episode log format: layout, topics, message schemas, versions.

Layout of a log (MCAP, one zstd chunk per step):

    Header
    Metadata "terl.log"           format version, policy name, sha256, path and metadata
    per episode, in order:
      Metadata "terl.episode"     file-order number, run index, seed, scenario JSON
      Chunk step 0                the state after reset: /world, /state
      Chunk step t = 1, 2, ...    /world, /actions, /target_weights, /rewards, [/events], /state
      Metadata "terl.episode_end" final metrics (missing when the run was interrupted)
    DataEnd, summary (schemas, channels, statistics, indexes), Footer, magic

Topics (log time = episode start + step * 0.5 s, in ns):

- `/world`: foxglove.SceneUpdate (terl_rt.logs.foxglove), the whole scene of the step, as
  Foxglove's own protobuf message with its schema (version 1 logs: JSON);
- `/state`: the world's public state (`terl_rt.sim.state.LOGGED_FIELDS`: `Simulator.state()`
  less the derived `pursuer_collided`), floats written with Python's repr, so they read
  back exactly;
- `/actions`: the [N] pursuer action indices fed to the simulator for this step
  (0 for collided pursuers), which pursuers decided, the [M] evader actions and, in runs
  under the shield, `shield_overrode`: [n] booleans, one per deciding pursuer, true where
  the shield replaced the policy's action (terl_rt.safety.shield);
- `/target_weights`: [n, E] target weights of the n deciding pursuers (policies with
  target selection only);
- `/rewards`: [N] rewards and their terms;
- `/events`: captures, collisions and the episode's end, in steps that have any.

Every topic but /world is JSON with a JSON Schema: Foxglove publishes no schema for
them (its plots and message panels read JSON as they read protobuf).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from terl_rt.logs.foxglove import SCENE_UPDATE, scene_update_schema
from terl_rt.sim.reward import REWARD_TERMS
from terl_rt.sim.simulator import StepInfo
from terl_rt.sim.state import LOGGED_FIELDS

LOG_FORMAT = "terl-rt episode log"
LOG_VERSION = "2"
"""Version of the layout above, the one the writer writes."""
READ_VERSIONS = ("1", "2")
"""Versions the reader reads: 1 (/world as JSON) and 2 (/world as protobuf); it refuses others."""

META_LOG = "terl.log"
META_EPISODE = "terl.episode"
META_EPISODE_END = "terl.episode_end"

TOPIC_WORLD = "/world"
TOPIC_STATE = "/state"
TOPIC_ACTIONS = "/actions"
TOPIC_TARGET_WEIGHTS = "/target_weights"
TOPIC_REWARDS = "/rewards"
TOPIC_EVENTS = "/events"


class EpisodeLogError(ValueError):
    """A file that is not a readable episode log; the message names the file and the problem."""


def encode(payload: Any) -> bytes:
    """A message or schema as compact JSON bytes."""
    return json.dumps(payload, separators=(",", ":")).encode()


def decode(data: bytes | str) -> Any:
    """A message or metadata value written by `encode` (or json.dumps), parsed. ValueError
    for anything else: bytes that are not UTF-8, text that is not JSON, JSON nested too
    deeply for the parser (what another tool, or damage, may leave in a log)."""
    try:
        return json.loads(data)
    except RecursionError:
        raise ValueError("JSON nested too deeply to read") from None


@dataclass(frozen=True)
class TopicSchema:
    """The schema of one topic's channel."""

    name: str
    """schema name, e.g. foxglove.SceneUpdate or terl.State."""
    encoding: str
    """MCAP schema encoding: "protobuf" (a FileDescriptorSet) or "jsonschema"."""
    data: bytes
    """the schema itself."""

    @property
    def message_encoding(self) -> str:
        """MCAP message encoding of the channel: "protobuf" or "json"."""
        return "protobuf" if self.encoding == "protobuf" else "json"


def _object_schema(title: str, description: str, properties: Mapping[str, Any]) -> TopicSchema:
    data = encode({"title": title, "description": description, "type": "object", "properties": dict(properties)})
    return TopicSchema(title, "jsonschema", data)


_NUMBERS = {"type": "array", "items": {"type": "number"}}
_INTEGERS = {"type": "array", "items": {"type": "integer"}}
_HEAD = {"episode": {"type": "integer"}, "step": {"type": "integer"}}
SCHEMAS: dict[str, TopicSchema] = {
    TOPIC_WORLD: TopicSchema(SCENE_UPDATE, "protobuf", scene_update_schema()),
    TOPIC_STATE: _object_schema(
        "terl.State", "Full world state after the step (m, rad, m/s); floats are exact float64 reprs",
        {**_HEAD, **{f.key: {"type": "array"} for f in LOGGED_FIELDS if f.key not in _HEAD}},
    ),
    TOPIC_ACTIONS: _object_schema(
        "terl.Actions", "Actions of the step: pursuer [N] as fed to the simulator, evader [M]; under a shield, "
        "shield_overrode [n]: the shield replaced the action of the deciding pursuer",
        {**_HEAD, "pursuer": _INTEGERS, "decided": _INTEGERS, "evader": _INTEGERS,
         "shield_overrode": {"type": "array", "items": {"type": "boolean"}}},
    ),
    TOPIC_TARGET_WEIGHTS: _object_schema(
        "terl.TargetWeights", "Target weights [n, E] of the pursuers that decided the step",
        {**_HEAD, "pursuer": _INTEGERS, "weights": {"type": "array", "items": _NUMBERS}},
    ),
    TOPIC_REWARDS: _object_schema(
        "terl.Rewards", "Reward [N] of each pursuer in the step and its terms",
        {**_HEAD, "total": _NUMBERS, "terms": {"type": "object", "properties": {t: _NUMBERS for t in REWARD_TERMS}}},
    ),
    TOPIC_EVENTS: _object_schema(
        "terl.Events", "Captures, collisions and the episode end in the step",
        {**_HEAD, "events": {"type": "array", "items": {"type": "object"}}},
    ),
}
"""topic -> the schema of its channel, for every channel of a log."""
TOPICS: tuple[str, ...] = tuple(SCHEMAS)
"""Every topic of a log."""


@dataclass(frozen=True)
class StepRecord:
    """What the log keeps of one step; step 0 is the state after reset (no actions)."""

    step: int
    state: dict[str, np.ndarray]
    """`Simulator.state()` after the step."""
    pursuer_actions: np.ndarray | None = None
    """[N] int64 fed to `Simulator.step` (None at step 0)."""
    decided: np.ndarray | None = None
    """[n] int64: pursuers that chose an action (the active ones)."""
    target_weights: np.ndarray | None = None
    """[n, E] float32 of the deciding pursuers, or None."""
    info: StepInfo | None = None
    """What the step did (None at step 0)."""
    overridden: np.ndarray | None = None
    """[n] bool: the shield overrode the policy's action of each deciding pursuer (None
    without a shield, and at step 0)."""
