"""The /world scene for Foxglove: Foxglove's own protobuf message and schema, and what is gone is deleted."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from google.protobuf.descriptor_pb2 import FileDescriptorSet
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from onnx_models import write_test_policy

from terl_rt import Scenario, Simulator
from terl_rt.cli.layout import layout_bytes
from terl_rt.evaluation.evaluate import evaluate_policy
from terl_rt.logs.format import TOPIC_WORLD
from terl_rt.logs.foxglove import (
    DELETE_ALL,
    DELETE_MATCHING_ID,
    entity_ids,
    scene_from_protobuf,
    scene_protobuf,
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


def test_every_world_message_decodes_with_the_schema_the_log_embeds(two_scenario_log):
    """A Foxglove-side reader (mcap's protobuf decoder, built from the log's own schema)
    reads every /world message as the scene terl-rt wrote."""
    written = [update for episode in scenes(two_scenario_log) for update in episode]
    with open(two_scenario_log, "rb") as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        decoded = [message for _, channel, _, message in reader.iter_decoded_messages(topics=[TOPIC_WORLD])]
    assert len(decoded) == len(written) == 2 * 5
    assert {message.DESCRIPTOR.full_name for message in decoded} == {"foxglove.SceneUpdate"}
    assert [scene_from_protobuf(message.SerializeToString()) for message in decoded] == written


def test_the_log_embeds_foxglove_s_published_scene_update_schema(two_scenario_log):
    reader = EpisodeLogReader(two_scenario_log)
    schema = next(s for s in reader.schemas.values() if s.name == "foxglove.SceneUpdate")
    files = FileDescriptorSet.FromString(schema.data).file
    assert schema.encoding == "protobuf"
    assert {"foxglove/SceneUpdate.proto", "google/protobuf/timestamp.proto"} <= {f.name for f in files}
    channel = next(c for c in reader.channels.values() if c.topic == TOPIC_WORLD)
    assert channel.message_encoding == "protobuf"


def test_a_scene_survives_the_protobuf_round_trip_unchanged():
    sim = Simulator(Scenario.preset("small-11"), seed=0)
    sim.reset()
    update = scene_update(sim.state(), (120.0, 120.0), 1_500_000_000, 0.5, 1.0, "status", previous_ids=["gone/0"])
    assert scene_from_protobuf(scene_protobuf(update)) == update


def test_a_scene_field_foxglove_does_not_define_is_refused():
    with pytest.raises(ValueError, match=r"foxglove.SceneEntity has no field 'colour'"):
        scene_protobuf({"entities": [{"id": "x", "colour": "red"}]})


def test_the_layout_opens_the_topics_the_logs_write():
    layout = json.loads(layout_bytes())
    text = json.dumps(layout)
    for topic in ("/world", "/rewards", "/target_weights", "/events"):
        assert topic in text, topic
    kinds = {panel_id.split("!")[0] for panel_id in layout["configById"]}
    assert {"3D", "Plot", "RawMessages"} <= kinds or {"3D", "Plot", "Log"} <= kinds, kinds
    three_d = next(config for key, config in layout["configById"].items() if key.startswith("3D"))
    assert three_d["topics"]["/world"]["visible"] is True
    assert np.isclose(three_d["cameraState"]["phi"], 0.0)  # looking straight down


def test_a_version_1_log_still_reads_its_json_world():
    reader = EpisodeLogReader(ROOT / "tests" / "data" / "world-v1.mcap")
    step = next(reader.steps(0))
    assert not step.protobuf
    assert "arena" in entity_ids(step.payload(TOPIC_WORLD))
