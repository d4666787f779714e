"""The messages of one step on the log's topics (terl_rt.logs.format), built once for every
sink that sends them: the MCAP log (terl_rt.logs.writer) and the live view (terl_rt.logs.live).

A sink numbers its episodes in the order it begins them. Step t of an episode has log time
start + t x the decision step (params.dt x params.substeps, 0.5 s), and the next episode
starts GAP_NS after the last step written, so log times only grow along a sink's episodes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from terl_rt.logs.format import (
    TOPIC_ACTIONS,
    TOPIC_EVENTS,
    TOPIC_REWARDS,
    TOPIC_STATE,
    TOPIC_TARGET_WEIGHTS,
    TOPIC_WORLD,
    StepRecord,
    encode,
)
from terl_rt.logs.foxglove import entity_ids, scene_protobuf, scene_update
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.state import LOGGED_FIELDS

GAP_NS = 1_000_000_000
"""ns: log time left between the last step of an episode and the next episode's start."""


class StepMessages(NamedTuple):
    """What a sink sends of one step."""

    time_ns: int
    """log time of every message of the step (ns)."""
    messages: list[tuple[str, bytes]]
    """(topic, encoded message) in the order written; /state, which marks a complete step, last."""
    scene_ids: list[str] | None
    """entity ids of the step's /world scene (None without one)."""


@dataclass
class OpenEpisode:
    """An episode a sink has begun: its number there, its scenario, its log times and the
    entity ids of the last /world scene sent (what the next scene deletes when gone)."""

    number: int
    scenario: Scenario
    offset_ns: int
    """ns: log time of step 0."""
    step_ns: int = field(init=False)
    """ns: log time between two steps (the decision step)."""
    last_ns: int = field(init=False)
    """ns: log time of the last step sent (step 0's until then)."""
    scene_ids: list[str] | None = None
    """entity ids of the last /world scene sent (None before the first)."""

    def __post_init__(self) -> None:
        params = self.scenario.params
        self.step_ns = int(round(params.dt * params.substeps * 1e9))
        self.last_ns = self.offset_ns

    @property
    def next_offset_ns(self) -> int:
        """ns: log time of the next episode's step 0, GAP_NS after this one's last step."""
        return self.last_ns + GAP_NS

    def messages(self, record: StepRecord, scenes: bool = True) -> StepMessages:
        """The messages of step `record` of this episode; `scenes`: with /world, Foxglove's 3-D
        scene (at step 0, or before any scene of the episode, it deletes every entity first)."""
        time_ns = self.offset_ns + record.step * self.step_ns
        head = {"episode": self.number, "step": record.step}
        state = record.state
        messages: list[tuple[str, Any]] = []
        scene_ids = None
        if scenes:
            params = self.scenario.params
            status = (
                f"{self.scenario.label}  episode {self.number}  step {record.step}  "
                f"t={record.step * self.step_ns / 1e9:g} s  "
                f"encircled {int((~state['evader_active']).sum())}/{len(state['evader_active'])}  "
                f"collided {int((~state['pursuer_active']).sum())}/{len(state['pursuer_active'])}"
            )
            scene = scene_update(
                state, self.scenario.arena, time_ns, params.robot_radius, params.vortex_core_radius, status,
                previous_ids=None if record.step == 0 else self.scene_ids, shielded=_shielded(record),
            )
            messages.append((TOPIC_WORLD, scene))
            scene_ids = entity_ids(scene)
        info = record.info
        if info is not None:
            actions = {
                **head,
                "pursuer": np.asarray(record.pursuer_actions).tolist(),
                "decided": np.asarray(record.decided).tolist(),
                "evader": info.evader_actions.tolist(),
            }
            if record.overridden is not None:
                actions["shield_overrode"] = np.asarray(record.overridden, bool).tolist()
            messages.append((TOPIC_ACTIONS, actions))
            if record.target_weights is not None:
                messages.append((TOPIC_TARGET_WEIGHTS, {
                    **head,
                    "pursuer": np.asarray(record.decided).tolist(),
                    "weights": np.asarray(record.target_weights).tolist(),
                }))
            messages.append((TOPIC_REWARDS, {
                **head,
                "total": info.reward.tolist(),
                "terms": {name: values.tolist() for name, values in info.reward_terms.items()},
            }))
            events = _events(record)
            if events:
                messages.append((TOPIC_EVENTS, {**head, "events": events}))
        # /state last: its presence marks the step as complete for readers of other tools.
        messages.append((TOPIC_STATE, _state_payload(self.number, state)))
        encoded = [(topic, scene_protobuf(payload) if topic == TOPIC_WORLD else encode(payload))
                   for topic, payload in messages]
        return StepMessages(time_ns, encoded, scene_ids)


def _events(record: StepRecord) -> list[dict]:
    info = record.info
    events: list[dict] = []
    for j in np.flatnonzero(info.captured).tolist():
        events.append({"type": "capture", "evader": j, "pursuers": np.flatnonzero(info.pursuer_target == j).tolist()})
    for i in np.flatnonzero(info.collided).tolist():
        events.append({"type": "collision", "pursuer": i})
    if info.terminated or info.truncated:
        success = not bool(record.state["evader_active"].any())
        events.append({
            "type": "episode_end", "success": success,
            "terminated": info.terminated, "truncated": info.truncated,
        })
    return events


def _shielded(record: StepRecord) -> list[int]:
    """The pursuers whose action the shield overrode in the step (none at step 0 or unshielded)."""
    if record.overridden is None:
        return []
    return np.asarray(record.decided)[np.asarray(record.overridden, bool)].tolist()


def _state_payload(number: int, state: Mapping[str, np.ndarray]) -> dict:
    payload: dict[str, Any] = {"episode": number}
    for f in LOGGED_FIELDS:
        payload[f.key] = np.asarray(state[f.key]).tolist()
    return payload
