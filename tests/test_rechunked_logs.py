"""A log another tool re-chunked (several steps per chunk, other compression) reads the same (issue 14, item 7)."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from onnx_models import write_test_policy
from tiny_worlds import capture_scenario

from terl_rt.cli.main import cli
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.logs.resimulate import verify


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("rechunk")
    scenario = folder / "capture.json"
    capture_scenario(max_steps=9).to_file(scenario)
    path = folder / "eval.mcap"
    result = CliRunner().invoke(cli, ["eval", "--policy", str(write_test_policy(folder / "linear.onnx")),
                                      "--scenario-file", str(scenario), "--episodes", "3", "--log", str(path)])
    assert result.exit_code == 0, result.output
    return path


def rechunk(source: Path, target: Path, chunk_size: int, compression: CompressionType, metadata_last: bool) -> None:
    """Copy every record of `source` into `target` with the mcap library's writer."""
    with open(source, "rb") as stream, open(target, "wb") as out:
        reader = make_reader(stream)
        writer = Writer(out, chunk_size=chunk_size, compression=compression)
        writer.start(profile="", library="rechunk-test")
        metadata = list(reader.iter_metadata())
        if not metadata_last:
            for record in metadata:
                writer.add_metadata(record.name, record.metadata)
        schema_ids, channel_ids = {}, {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if schema.id not in schema_ids:
                schema_ids[schema.id] = writer.register_schema(schema.name, schema.encoding, schema.data)
            if channel.id not in channel_ids:
                channel_ids[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schema_ids[schema.id], channel.metadata,
                )
            writer.add_message(channel_ids[channel.id], message.log_time, message.data, message.publish_time,
                               message.sequence)
        if metadata_last:
            for record in metadata:
                writer.add_metadata(record.name, record.metadata)
        writer.finish()


@pytest.mark.parametrize("chunk_size, compression, metadata_last", [
    (60_000, CompressionType.LZ4, False),
    (200_000, CompressionType.NONE, True),
    (10**9, CompressionType.ZSTD, False),  # the whole log in one chunk
])
def test_a_rechunked_log_lists_reads_and_verifies_like_the_original(log, tmp_path, chunk_size, compression,
                                                                    metadata_last):
    target = tmp_path / "rechunked.mcap"
    rechunk(log, target, chunk_size, compression, metadata_last)
    original, copy = EpisodeLogReader(log), EpisodeLogReader(target)
    assert copy.indexed and not copy.truncated
    assert len(copy.episodes[0].chunks) < copy.episodes[0].steps + 1  # several steps per chunk
    assert [(e.index, e.seed, e.steps, e.metrics) for e in copy.episodes] == [
        (e.index, e.seed, e.steps, e.metrics) for e in original.episodes
    ]
    assert [e.steps for e in copy.episodes] == [9, 9, 9]
    for number in range(3):
        mine = [(s.step, s.messages) for s in original.steps(number)]
        assert [(s.step, s.messages) for s in copy.steps(number)] == mine
    assert copy.message_counts() == original.message_counts()
    assert all(verify(target, number).ok for number in range(3))
    result = CliRunner().invoke(cli, ["replay", str(target), "--verify"])
    assert result.exit_code == 0, result.output
    assert result.stdout.count("bit-identical") == 3
