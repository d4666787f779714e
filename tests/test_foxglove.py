"""The /world scene for Foxglove: checked against Foxglove's own schema, and what is gone is deleted."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from onnx_models import write_test_policy

from terl_rt import Scenario, Simulator
from terl_rt.evaluation.episodes import evaluate_policy
from terl_rt.logs.format import TOPIC_WORLD
from terl_rt.logs.foxglove import (
    DELETE_ALL,
    DELETE_MATCHING_ID,
    SCENE_UPDATE_SCHEMA,
    entity_ids,
    official_scene_update_schema,
    scene_update,
)
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.logs.writer import EpisodeLogWriter
from terl_rt.policy.onnx_policy import OnnxPolicy, policy_info

ROOT = Path(__file__).parents[1]


@pytest.fixture(scope="module")
def two_scenario_log(tmp_path_factory) -> Path:
    """small-19 then small-11 in one log (as `eval --scenario small-19 --scenario small-11 --log`)."""
    folder = tmp_path_factory.mktemp("foxglove")
    policy = OnnxPolicy(write_test_policy(folder / "linear.onnx"))
    path = folder / "two.mcap"
    with EpisodeLogWriter(path, policy_info(policy)) as log:
        for name in ("small-19", "small-11"):
            evaluate_policy(policy, Scenario.preset(name), episodes=1, seed=0, max_steps=4, log_path=log)
    return path


def scenes(path: Path) -> list[list[dict]]:
    reader = EpisodeLogReader(path)
    return [[step.payload(TOPIC_WORLD) for step in reader.steps(e.number)] for e in reader.episodes]


class Panel:
    """What Foxglove's 3D panel holds of a topic: deletions apply first, then entities."""

    def __init__(self) -> None:
        self.entities: dict[str, dict] = {}

    def apply(self, update: dict) -> None:
        for deletion in update["deletions"]:
            if deletion["type"] == DELETE_ALL:
                self.entities.clear()
            else:
                self.entities.pop(deletion["id"], None)
        for entity in update["entities"]:
            self.entities[entity["id"]] = entity


def test_the_next_episode_leaves_nothing_of_the_last_on_screen(two_scenario_log):
    first, second = scenes(two_scenario_log)
    panel = Panel()
    for update in first:
        panel.apply(update)
    assert "pursuer/18" in panel.entities and "evader/4" in panel.entities
    panel.apply(second[0])
    assert second[0]["deletions"][0]["type"] == DELETE_ALL
    assert set(panel.entities) == set(entity_ids(second[0]))
    gone = {f"pursuer/{i}" for i in range(11, 19)} | {"evader/3", "evader/4"}
    assert not gone & set(panel.entities)
    for update in second[1:]:
        panel.apply(update)
        assert set(panel.entities) == set(entity_ids(update))


def test_an_entity_that_disappears_is_deleted_by_id():
    sim = Simulator(Scenario.preset("small-11"), seed=0)
    sim.reset()
    state = sim.state()
    update = scene_update(state, (120.0, 120.0), 5, 0.5, 1.0, previous_ids=["arena", "pursuer/0", "pursuer/99"])
    assert update["deletions"] == [
        {"timestamp": {"sec": 0, "nsec": 5}, "type": DELETE_MATCHING_ID, "id": "pursuer/99"}
    ]
    same = scene_update(state, (120.0, 120.0), 5, 0.5, 1.0, previous_ids=entity_ids(update))
    assert same["deletions"] == []


def test_every_world_message_validates_against_foxglove_s_own_schema(two_scenario_log):
    jsonschema = pytest.importorskip("jsonschema")
    pytest.importorskip("foxglove_schemas_protobuf")
    validator = jsonschema.Draft202012Validator(official_scene_update_schema(strict=True))
    count = 0
    for episode in scenes(two_scenario_log):
        for update in episode:
            errors = sorted(validator.iter_errors(update), key=lambda e: list(e.path))
            assert not errors, f"{list(errors[0].path)}: {errors[0].message}"
            count += 1
    assert count == 2 * 5


def test_the_schema_in_the_logs_has_foxglove_s_fields_and_types():
    """SCENE_UPDATE_SCHEMA (embedded in every log) mirrors the official definition."""
    pytest.importorskip("foxglove_schemas_protobuf")
    official = official_scene_update_schema()

    def shape(schema: dict):
        if "enum" in schema or "oneOf" in schema:
            return "enum"
        kind = schema.get("type")
        if kind == "object":
            return {name: shape(sub) for name, sub in schema["properties"].items()}
        if kind == "array":
            return [shape(schema["items"])]
        return kind

    assert shape(SCENE_UPDATE_SCHEMA) == shape(official)
    jsonschema = pytest.importorskip("jsonschema")
    jsonschema.Draft202012Validator.check_schema(SCENE_UPDATE_SCHEMA)


def test_the_layout_opens_the_topics_the_logs_write():
    layout = json.loads((ROOT / "docs" / "foxglove-layout.json").read_text())
    text = json.dumps(layout)
    for topic in ("/world", "/rewards", "/target_weights", "/events"):
        assert topic in text, topic
    kinds = {panel_id.split("!")[0] for panel_id in layout["configById"]}
    assert {"3D", "Plot", "RawMessages"} <= kinds or {"3D", "Plot", "Log"} <= kinds, kinds
    three_d = next(config for key, config in layout["configById"].items() if key.startswith("3D"))
    assert three_d["topics"]["/world"]["visible"] is True
    assert np.isclose(three_d["cameraState"]["phi"], 0.0)  # looking straight down
