"""MCAP episode logs: round trip, Foxglove schema, metadata, truncated and corrupt files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from onnx_models import write_test_policy
from tiny_worlds import capture_scenario

from terl_rt.evaluation.evaluate import evaluate_policy as evaluate
from terl_rt.evaluation.play import run_episode
from terl_rt.logs.format import TOPIC_WORLD, EpisodeLogError
from terl_rt.logs.foxglove import COLORS
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.logs.writer import EpisodeLogWriter
from terl_rt.policy.onnx_policy import OnnxPolicy, policy_info

STEPS = 6
"""Step limit of the logged episodes."""


@pytest.fixture(scope="module")
def policy(tmp_path_factory) -> OnnxPolicy:
    return OnnxPolicy(write_test_policy(tmp_path_factory.mktemp("policy") / "linear.onnx"))


@pytest.fixture(scope="module")
def log_path(policy, tmp_path_factory) -> Path:
    """Two episodes of the capture scenario (a capture and two collisions in step 1)."""
    path = tmp_path_factory.mktemp("logs") / "capture.mcap"
    evaluate(policy, capture_scenario(STEPS), episodes=2, seed=3, log_path=path)
    return path


def episode_records(policy, seed: int = 0) -> list:
    """The StepRecords of one capture-scenario episode."""
    records = []
    run_episode(policy, capture_scenario(STEPS), seed=seed, on_step=records.append)
    return records


def open_writer(policy, path: Path) -> EpisodeLogWriter:
    """A writer at `path` with episode 0 of the capture scenario begun (seed 0)."""
    writer = EpisodeLogWriter(path, policy_info(policy))
    writer.begin_episode(capture_scenario(STEPS), seed=0, index=0)
    return writer


def test_log_lists_its_episodes_with_scenario_seed_and_metrics(log_path):
    reader = EpisodeLogReader(log_path)
    assert not reader.truncated and reader.problem is None
    assert reader.policy["name"] == "linear-test" and len(reader.policy["sha256"]) == 64
    episodes = reader.episodes
    assert [(e.number, e.index, e.seed, e.steps) for e in episodes] == [(0, 0, 3, STEPS), (1, 1, 4, STEPS)]
    assert episodes[0].scenario == capture_scenario(STEPS)
    assert episodes[0].complete and episodes[0].metrics.evaders_encircled == 1


def test_log_has_the_foxglove_scene_schema_and_every_topic(log_path):
    assert EpisodeLogReader(log_path).topics == {
        "/world": "foxglove.SceneUpdate",
        "/state": "terl.State",
        "/actions": "terl.Actions",
        "/target_weights": "terl.TargetWeights",
        "/rewards": "terl.Rewards",
        "/events": "terl.Events",
    }


def test_message_counts_per_topic(log_path):
    # Per episode: STEPS + 1 frames (reset included) of /world and /state, STEPS of the
    # per-step topics, and /events in step 1 (capture, collisions) and the last (end).
    frames, steps = 2 * (STEPS + 1), 2 * STEPS
    assert EpisodeLogReader(log_path).message_counts() == {
        "/world": frames, "/state": frames, "/actions": steps, "/target_weights": steps,
        "/rewards": steps, "/events": 4,
    }


def test_standard_mcap_reader_sees_the_same_log(log_path):
    with open(log_path, "rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary.statistics.message_count == 2 * (STEPS + 1) * 2 + 2 * STEPS * 3 + 4
        names = [record.name for record in reader.iter_metadata()]
        assert names == ["terl.log", "terl.episode", "terl.episode_end", "terl.episode", "terl.episode_end"]
        episode = next(r for r in reader.iter_metadata() if r.name == "terl.episode")
        assert json.loads(episode.metadata["scenario"])["name"] == "tiny-capture"
        assert episode.metadata["policy"] == "linear-test" and episode.metadata["seed"] == "3"
        end = next(r for r in reader.iter_metadata() if r.name == "terl.episode_end")
        assert json.loads(end.metadata["metrics"])["pursuers_collided"] == 2


def test_logged_states_read_back_bit_for_bit(policy, log_path):
    records = episode_records(policy, seed=3)
    logged = list(EpisodeLogReader(log_path).steps(0))
    assert [s.step for s in logged] == list(range(STEPS + 1))
    for record, step in zip(records, logged):
        for name, value in step.state.items():
            original = np.asarray(record.state[name])
            assert value.dtype == original.dtype and value.tobytes() == original.tobytes(), name


def test_state_message_holds_the_public_state_and_no_bookkeeping_of_the_rules(log_path):
    step = next(EpisodeLogReader(log_path).steps(0))
    assert list(step.payload("/state")) == [
        "episode",
        "pursuer_xy", "pursuer_theta", "pursuer_speed", "pursuer_vel", "pursuer_active",
        "evader_xy", "evader_theta", "evader_speed", "evader_vel", "evader_active",
        "obstacle_xy", "obstacle_r", "vortex_xy", "vortex_gamma", "vortex_clockwise", "step",
    ]


def test_logged_step_one_holds_actions_rewards_and_events(log_path):
    step = list(EpisodeLogReader(log_path).steps(0))[1]
    assert step.pursuer_actions.shape == (7,) and step.evader_actions.shape == (2,)
    assert step.payload("/target_weights")["pursuer"] == list(range(7))
    assert np.array(step.payload("/target_weights")["weights"]).shape == (7, 4)
    assert len(step.payload("/rewards")["total"]) == 7
    kinds = [(e["type"], e.get("evader", e.get("pursuer"))) for e in step.events]
    assert kinds == [("capture", 0), ("collision", 3), ("collision", 4)]
    assert step.events[0]["pursuers"] == [0, 1, 2]


def test_scene_updates_keep_their_entity_ids_across_steps(log_path):
    steps = list(EpisodeLogReader(log_path).steps(0))
    scenes = [step.payload(TOPIC_WORLD) for step in steps]
    ids = [[entity["id"] for entity in scene["entities"]] for scene in scenes]
    assert all(frame == ids[0] for frame in ids)
    assert {"arena", "pursuer/0", "pursuer/6", "evader/0", "evader/1", "obstacle/0", "vortex/0", "vortex/1"} <= set(ids[0])


def test_encircled_evader_changes_colour(log_path):
    def evader_colour(scene, j):
        entity = next(e for e in scene["entities"] if e["id"] == f"evader/{j}")
        c = entity["spheres"][0]["color"]
        return (c["r"], c["g"], c["b"], c["a"])

    before, after = (step.payload(TOPIC_WORLD) for step in list(EpisodeLogReader(log_path).steps(0))[:2])
    assert evader_colour(before, 0) == COLORS["evader"]
    assert evader_colour(after, 0) == COLORS["evader_encircled"]
    assert evader_colour(after, 1) == COLORS["evader"]


def test_truncated_file_reads_back_up_to_its_last_complete_step(log_path, tmp_path):
    data = log_path.read_bytes()
    cut_path = tmp_path / "cut.mcap"
    readable = []
    for cut in np.linspace(0, len(data) - 1, 41).astype(int).tolist():
        cut_path.write_bytes(data[:cut])
        try:
            reader = EpisodeLogReader(cut_path)
        except EpisodeLogError as error:
            # Cut before the log's first records: nothing to read, and it says so.
            assert readable == [], f"cut at {cut} failed after longer prefixes read: {error}"
            assert "cut off" in str(error) or "empty" in str(error)
            continue
        assert reader.truncated and "cut off" in reader.problem
        steps = sum(len(list(reader.steps(e.number))) for e in reader.episodes)
        readable.append(steps)
    assert readable == sorted(readable), "a longer prefix never reads fewer steps"
    assert readable[-1] == 2 * (STEPS + 1)  # cut in the summary: every step intact


def test_unclosed_writer_leaves_a_readable_log(policy, tmp_path):
    path = tmp_path / "open.mcap"
    writer = open_writer(policy, path)
    records = episode_records(policy)
    for record in records[:3]:
        writer.write_step(record)
    reader = EpisodeLogReader(path)  # while the writer is still open
    assert reader.truncated and "never closed" in reader.problem
    (episode,) = reader.episodes
    assert not episode.complete and [s.step for s in reader.steps(0)] == [0, 1, 2]
    writer.close()
    reader = EpisodeLogReader(path)
    assert not reader.truncated and reader.episodes[0].steps == 2 and not reader.episodes[0].complete


def test_corrupt_chunk_is_an_error_naming_its_offset(log_path, tmp_path):
    data = bytearray(log_path.read_bytes())
    reader = EpisodeLogReader(log_path)
    offset, length = reader.episodes[1].chunks[2]
    data[offset + length // 2] ^= 0xFF
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(bytes(data))
    with pytest.raises(EpisodeLogError, match=rf"corrupt chunk at byte {offset} \(episode 1, step 2\)"):
        list(EpisodeLogReader(broken).steps(1))


@pytest.mark.parametrize("content, message", [
    (b"", "empty"),
    (b"PK\x03\x04 a zip file, not a log", "not an MCAP file"),
    (b"\x89MC", "cut off inside the MCAP magic"),
])
def test_files_that_are_not_logs_are_refused(tmp_path, content, message):
    path = tmp_path / "bad.mcap"
    path.write_bytes(content)
    with pytest.raises(EpisodeLogError, match=message):
        EpisodeLogReader(path)


def test_other_mcap_files_are_not_episode_logs(tmp_path):
    path = tmp_path / "other.mcap"
    with open(path, "wb") as stream:
        writer = Writer(stream)
        writer.start()
        writer.add_metadata("something", {"a": "b"})
        writer.finish()
    with pytest.raises(EpisodeLogError, match="not a terl-rt episode log"):
        EpisodeLogReader(path)


def test_missing_log_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError):
        EpisodeLogReader(tmp_path / "absent.mcap")


def test_asking_for_an_absent_episode_names_the_range(log_path):
    with pytest.raises(EpisodeLogError, match="no episode 7; the log holds episodes 0-1"):
        EpisodeLogReader(log_path).episode(7)


def test_step_interrupted_half_way_never_reaches_the_file(policy, tmp_path):
    path = tmp_path / "half.mcap"
    records = episode_records(policy)
    writer = open_writer(policy, path)
    for record in records[:2]:
        writer.write_step(record)
    add_message, calls = writer._mcap.add_message, []

    def interrupted(**kwargs):  # Ctrl-C after the third message of step 2
        calls.append(kwargs)
        if len(calls) == 3:
            raise KeyboardInterrupt
        add_message(**kwargs)

    writer._mcap.add_message = interrupted
    with pytest.raises(KeyboardInterrupt):
        writer.write_step(records[2])
    writer.close()
    reader = EpisodeLogReader(path)
    assert reader.truncated and "the last complete step is episode 0 step 1" in reader.problem
    assert [step.step for step in reader.steps(0)] == [0, 1]


def test_ctrl_c_during_a_step_waits_until_the_step_is_on_disk(policy, tmp_path):
    import os
    import signal

    path = tmp_path / "ctrl-c.mcap"
    records = episode_records(policy)
    writer = open_writer(policy, path)
    add_message, calls = writer._mcap.add_message, []

    def interrupted(**kwargs):  # Ctrl-C arrives after the second message of step 0
        calls.append(kwargs)
        if len(calls) == 2:
            os.kill(os.getpid(), signal.SIGINT)
        add_message(**kwargs)

    writer._mcap.add_message = interrupted
    with pytest.raises(KeyboardInterrupt):
        writer.write_step(records[0])
    writer.close()
    reader = EpisodeLogReader(path)
    assert not reader.truncated  # the step finished, then the summary was written
    assert [step.step for step in reader.steps(0)] == [0]
