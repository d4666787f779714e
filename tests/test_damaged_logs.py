"""Logs with damaged bytes (issue 55): a chunk that fails its CRC check is named by every
command that reads the log, and the episodes it does not touch read, render and verify
as they are; a log cut off anywhere is noted alike by each (issue 78, item 2). The damage
is done to copies of the shared log of 2 small-11 episodes of 30 steps (conftest.logged_eval)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader
from one_line import assert_one_error, invoke

from terl_rt.logs.format import TOPIC_STATE, EpisodeLogError
from terl_rt.logs.reader import EpisodeLogReader


def _damaged_copy(log: Path, folder: Path, damage) -> Path:
    """A copy of `log` in `folder` whose bytes `damage(bytearray, reader)` changed in place."""
    data = bytearray(log.read_bytes())
    damage(data, EpisodeLogReader(log))
    copy = folder / "damaged.mcap"
    copy.write_bytes(bytes(data))
    return copy


def _flip_inside_chunk_10_of_episode_0(data: bytearray, reader: EpisodeLogReader) -> None:
    offset, length = reader.episodes[0].chunks[10]
    data[offset + length // 2] ^= 0x01


def _zero_episode_0(data: bytearray, reader: EpisodeLogReader) -> None:
    """Zero every byte from episode 0's first chunk to the end of its last one."""
    chunks = reader.episodes[0].chunks
    start, end = chunks[0][0], chunks[-1][0] + 9 + chunks[-1][1]
    data[start:end] = bytes(end - start)


@pytest.fixture
def flipped(logged_eval, tmp_path) -> Path:
    return _damaged_copy(logged_eval["log"], tmp_path, _flip_inside_chunk_10_of_episode_0)


def test_listing_a_log_names_a_chunk_that_fails_its_crc_check(logged_eval, flipped):
    offset = EpisodeLogReader(logged_eval["log"]).episodes[0].chunks[10][0]
    result = invoke("replay", flipped)
    assert result.exit_code == 0, result.output
    assert f"fail their CRC check or do not parse, the first at byte {offset}" in result.stderr
    lines = result.stdout.splitlines()
    assert "DAMAGED" in lines[2] and "DAMAGED" not in lines[3], result.stdout
    listed = json.loads(invoke("replay", flipped, "--json").stdout)
    assert [e["damaged_chunks"] for e in listed["episodes"]] == [[offset], []]
    assert [e["steps"] for e in listed["episodes"]] == [9, 30]  # episode 0 reads steps 0-9


def test_a_damaged_episode_serves_its_steps_up_to_the_damage_then_names_it(flipped):
    steps = EpisodeLogReader(flipped).steps(0)
    assert [next(steps).step for _ in range(10)] == list(range(10))
    with pytest.raises(EpisodeLogError, match=r"corrupt chunk at byte \d+ \(episode 0, step 10\)"):
        next(steps)


def test_a_flipped_time_in_a_message_index_moves_no_step_to_another_episode(logged_eval, tmp_path):
    def flip_a_state_time(data: bytearray, reader: EpisodeLogReader) -> None:
        with open(logged_eval["log"], "rb") as stream:
            summary = make_reader(stream).get_summary()
        state = next(cid for cid, channel in summary.channels.items() if channel.topic == TOPIC_STATE)
        chunk = min(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)  # episode 0, step 0
        # Message index: opcode (1), length (8), channel id (2), records length (4), then
        # (log time, offset) pairs of 8 bytes each; +2**56 ns moves step 0 past every episode's start.
        data[chunk.message_index_offsets[state] + 9 + 2 + 4 + 7] ^= 0x01

    damaged = _damaged_copy(logged_eval["log"], tmp_path, flip_a_state_time)
    assert [e.steps for e in EpisodeLogReader(damaged).episodes] == [30, 30]


def test_with_episode_0_zeroed_episode_1_renders_and_verifies(logged_eval, tmp_path):
    damaged = _damaged_copy(logged_eval["log"], tmp_path, _zero_episode_0)
    rendered = invoke("render", damaged, "--episode", "1", "-o", tmp_path / "episode-1.png")
    assert rendered.exit_code == 0 and (tmp_path / "episode-1.png").is_file(), rendered.output
    assert_one_error(invoke("render", damaged, "--episode", "0", "-o", tmp_path / "episode-0.png"),
                     "corrupt chunk at byte", "(episode 0, step 0)")
    verified = invoke("replay", damaged, "--verify")
    assert verified.exit_code == 1, verified.output
    episode_0, episode_1 = verified.stdout.splitlines()
    assert "MISMATCH at step 0, log:" in episode_0 and "ok, 30 steps bit-identical" in episode_1


def test_a_cut_off_log_with_a_damaged_chunk_says_both(logged_eval, tmp_path):
    def cut_after_episode_0_and_flip(data: bytearray, reader: EpisodeLogReader) -> None:
        _flip_inside_chunk_10_of_episode_0(data, reader)
        offset, length = reader.episodes[1].chunks[5]
        del data[offset + 9 + length:]

    reader = EpisodeLogReader(_damaged_copy(logged_eval["log"], tmp_path, cut_after_episode_0_and_flip))
    assert reader.truncated and "cut off" in reader.problem and "fail their CRC check" in reader.problem
    assert [(e.steps, bool(e.damaged)) for e in reader.episodes] == [(9, True), (5, False)]


CUTS = 24
"""offsets a log is cut at, evenly over its bytes, plus the start of every tenth chunk."""


def _cut_offsets(log: Path) -> list[int]:
    size = log.stat().st_size
    chunk_starts = [offset for episode in EpisodeLogReader(log).episodes for offset, _ in episode.chunks]
    return sorted({size * k // CUTS for k in range(1, CUTS)} | set(chunk_starts[::10]))


def test_render_replay_and_verify_say_alike_where_a_log_was_cut_off(logged_eval, tmp_path):
    """At any cut each reads up to the last complete step and notes the cut, or all three
    end in the same one line (nothing readable; render: no complete step to draw)."""
    data = logged_eval["log"].read_bytes()
    for offset in _cut_offsets(logged_eval["log"]):
        cut = tmp_path / f"cut-{offset}.mcap"
        cut.write_bytes(data[:offset])
        replayed, verified = invoke("replay", cut), invoke("replay", cut, "--verify")
        rendered = invoke("render", cut, "-o", tmp_path / f"cut-{offset}.png", "--size", 64)
        try:
            reader = EpisodeLogReader(cut)
        except EpisodeLogError as error:
            for result in (replayed, verified, rendered):
                assert_one_error(result, str(error))
            continue
        note = f"note: {reader.problem}\n"
        assert reader.truncated and "cut off" in reader.problem, offset
        assert replayed.exit_code == 0 and replayed.stderr.endswith(note), (offset, replayed.output)
        assert verified.exit_code == 0 and verified.stderr.endswith(note), (offset, verified.output)
        if reader.episodes[0].chunks:
            assert rendered.exit_code == 0 and rendered.stderr.endswith(note), (offset, rendered.output)
        else:
            assert_one_error(rendered, "episode 0 has no complete step to draw", reader.problem)
