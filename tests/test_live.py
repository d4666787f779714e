"""The live view in Foxglove (terl_rt.logs.live): a client of Foxglove's WebSocket protocol sees
the steps of an evaluation, or of a replayed log, as the log holds them; a slow or vanished
client holds no run back; --live fails in one line without the extra (issue 76, part 1).
Servers listen on 127.0.0.1 only, on ports the system picks."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("foxglove", reason="the live extra (foxglove-sdk)")
pytest.importorskip("websockets", reason="the dev extra's websockets, the test client")

from click.testing import CliRunner  # noqa: E402
from foxglove_client import DEADLINE_S, FoxgloveClient, wait_for  # noqa: E402
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate  # noqa: E402
from onnx_models import write_test_policy  # noqa: E402

import terl_rt  # noqa: E402
from terl_rt.cli.main import cli  # noqa: E402
from terl_rt.logs.format import SCHEMAS, TOPIC_STATE, TOPIC_WORLD, TOPICS  # noqa: E402
from terl_rt.logs.foxglove import DELETE_ALL  # noqa: E402
from terl_rt.logs.live import DEFAULT_HOST, LiveSink, parse_address, stream_log  # noqa: E402
from terl_rt.logs.reader import EpisodeLogReader  # noqa: E402
from terl_rt.sim.scenario import Scenario  # noqa: E402

HOST = "127.0.0.1"
SCENARIO = Scenario.preset("small-11").replace(max_steps=8)
ROOT = Path(__file__).parents[1]


@pytest.fixture(scope="module")
def policy_path(tmp_path_factory) -> Path:
    return write_test_policy(tmp_path_factory.mktemp("policy") / "linear.onnx")


@pytest.fixture(scope="module")
def kept_log(policy_path, tmp_path_factory) -> Path:
    """Two episodes of SCENARIO, logged."""
    log = tmp_path_factory.mktemp("kept") / "kept.mcap"
    terl_rt.evaluate(policy_path, SCENARIO, episodes=2, seed=1, log=log)
    return log


@pytest.fixture
def live():
    with LiveSink(HOST, 0) as sink:
        yield sink


def logged(path: Path, topic: str) -> list[tuple[int, bytes]]:
    """(log time, message) of `topic` at every step of every episode of the log at `path`."""
    reader = EpisodeLogReader(path)
    return [(step.time_ns, step.messages[topic]) for e in reader.episodes for step in reader.steps(e.number)]


def assert_scenes_as_logged(received: list[tuple[int, bytes]], path: Path) -> None:
    """The SceneUpdates received, decoded as protobuf, are the log's, step by step and entity by entity."""
    expected = logged(path, TOPIC_WORLD)
    assert [time_ns for time_ns, _ in received] == [time_ns for time_ns, _ in expected]
    for (_, live), (_, kept) in zip(received, expected):
        ours, theirs = SceneUpdate.FromString(live), SceneUpdate.FromString(kept)
        assert [entity.id for entity in ours.entities] == [entity.id for entity in theirs.entities]
        assert ours == theirs


def refuses_connections(port: int) -> bool:
    try:
        socket.create_connection((HOST, port), timeout=DEADLINE_S).close()
    except ConnectionRefusedError:
        return True
    return False


def test_a_client_sees_every_scene_of_an_evaluation_as_the_log_holds_it(policy_path, live, tmp_path):
    client = FoxgloveClient(live.url)
    client.subscribe(TOPIC_WORLD, TOPIC_STATE)
    wait_for(lambda: live.watched(TOPIC_WORLD) and live.watched(TOPIC_STATE), "the subscriptions to arrive")
    log = tmp_path / "run.mcap"
    terl_rt.evaluate(policy_path, [SCENARIO, "small-15"], episodes=2, seed=3, max_steps=6, log=[log, live])
    steps = len(logged(log, TOPIC_STATE))
    wait_for(lambda: len(client.received[TOPIC_STATE]) == steps, f"{steps} steps")
    assert set(client.channels) == set(TOPICS)
    world = client.channels[TOPIC_WORLD]
    assert (world["schemaName"], world["encoding"], world["schemaEncoding"]) == (
        "foxglove.SceneUpdate", "protobuf", "protobuf")
    assert client.received[TOPIC_STATE] == logged(log, TOPIC_STATE)
    assert_scenes_as_logged(client.received[TOPIC_WORLD], log)
    client.close()


def test_a_client_that_stalls_or_vanishes_holds_the_run_back_nowhere(policy_path):
    alone = terl_rt.evaluate(policy_path, SCENARIO, episodes=3, max_steps=150).result.per_episode
    with LiveSink(HOST, 0, backlog=4) as live:
        stalled = FoxgloveClient(live.url, reading=False, receive_buffer=4096)
        stalled.subscribe(*TOPICS)
        gone = FoxgloveClient(live.url)
        gone.subscribe(TOPIC_WORLD)
        wait_for(lambda: live.watched(TOPIC_STATE) and live.watched(TOPIC_WORLD), "the subscriptions to arrive")
        results = []
        run = threading.Thread(target=lambda: results.append(
            terl_rt.evaluate(policy_path, SCENARIO, episodes=3, max_steps=150, log=live).result.per_episode))
        run.start()
        wait_for(lambda: gone.received[TOPIC_WORLD] or not run.is_alive(), "the first scene")
        gone.vanish()
        run.join(DEADLINE_S)
        assert not run.is_alive(), "the run waited on a client"
    stalled.vanish()  # after the server closed without waiting on it
    assert results == [alone]


def test_stream_log_sends_a_log_at_its_log_times(kept_log, live):
    log = kept_log
    client = FoxgloveClient(live.url)
    client.subscribe(TOPIC_WORLD)
    wait_for(lambda: live.watched(TOPIC_WORLD), "the subscription to arrive")
    expected = logged(log, TOPIC_WORLD)
    rate = 40.0
    start = time.monotonic()
    sent = stream_log(EpisodeLogReader(log), live, [0, 1], rate=rate)
    took = time.monotonic() - start
    assert sent == len(expected)
    span_s = (expected[-1][0] - expected[0][0]) / 1e9  # two episodes of 8 steps (4 s), a second apart
    assert took >= span_s / rate
    wait_for(lambda: len(client.received[TOPIC_WORLD]) == sent, f"{sent} scenes")
    assert_scenes_as_logged(client.received[TOPIC_WORLD], log)
    client.close()


def test_replay_live_serves_a_log_to_the_client_that_subscribes(kept_log):
    log, first = kept_log, EpisodeLogReader(kept_log).episode(0).steps + 1
    process = subprocess.Popen(
        [sys.executable, "-m", "terl_rt", "replay", str(log), "--episode", "1", "--live", f"{HOST}:0",
         "--rate", "100"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        announced = process.stderr.readline()  # blocks until the server is up (or the command fails)
        assert announced.startswith(f"live: ws://{HOST}:"), announced + process.stderr.read()
        client = FoxgloveClient(announced.split()[1])
        client.subscribe(TOPIC_WORLD)
        out, err = process.communicate(timeout=DEADLINE_S)
    finally:
        process.kill()
    assert process.returncode == 0, err
    assert out.strip() == f"streamed {len(logged(log, TOPIC_WORLD)) - first} steps of 1 episode(s) of {log}"
    wait_for(lambda: client.closed.is_set(), "the server to close")
    assert client.received[TOPIC_WORLD] == logged(log, TOPIC_WORLD)[first:]


def test_eval_live_serves_while_it_runs_and_closes_after(policy_path):
    result = CliRunner().invoke(cli, ["eval", "--policy", str(policy_path), "--scenario", "small-11",
                                      "--episodes", "1", "--max-steps", "3", "--live", f"{HOST}:0"])
    assert result.exit_code == 0, result.output
    line = next(line for line in result.stderr.splitlines() if line.startswith("live: "))
    assert line.startswith(f"live: ws://{HOST}:") and "Ctrl-C stops" in line
    assert refuses_connections(int(line.split()[1].rsplit(":", 1)[1]))


def test_ctrl_c_stops_a_run_served_live_and_closes_the_server(policy_path):
    process = subprocess.Popen(
        [sys.executable, "-m", "terl_rt", "eval", "--policy", str(policy_path), "--episodes", "100000",
         "--live", f"{HOST}:0"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        url = process.stderr.readline().split()[1]
        client = FoxgloveClient(url)
        client.subscribe(TOPIC_WORLD)
        wait_for(lambda: client.received[TOPIC_WORLD], "a scene")
        process.send_signal(signal.SIGINT)
        _, err = process.communicate(timeout=DEADLINE_S)
    finally:
        process.kill()
    assert process.returncode == 130 and err.strip().splitlines()[-1] == "Error: stopped by SIGINT", err
    wait_for(client.closed.is_set, "the server to close")
    assert refuses_connections(int(url.rsplit(":", 1)[1]))
    # Subscribed in the middle of an episode, the client's first scene clears the panel first.
    assert SceneUpdate.FromString(client.received[TOPIC_WORLD][0][1]).deletions[0].type == DELETE_ALL


def test_live_on_a_port_taken_fails_in_one_line(policy_path):
    with socket.socket() as taken:
        taken.bind((HOST, 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = CliRunner().invoke(cli, ["eval", "--policy", str(policy_path), "--live", f"{HOST}:{port}"])
    assert result.exit_code == 2
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith(f"Error: cannot serve the live view on {HOST}:{port}: ") and "in use" in line


@pytest.mark.parametrize("command", ["eval", "replay"])
def test_live_without_the_foxglove_sdk_names_the_extra_in_one_line(command, policy_path, kept_log, monkeypatch):
    monkeypatch.setitem(sys.modules, "foxglove", None)  # `import foxglove` fails as when not installed
    given = ["eval", "--policy", str(policy_path)] if command == "eval" else ["replay", str(kept_log)]
    result = CliRunner().invoke(cli, [*given, "--live"])
    assert result.exit_code == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "terl-rt[live]" in lines[0] and lines[0].startswith("Error: the live view needs")


@pytest.mark.parametrize("given, expected", [
    ("127.0.0.1:8765", ("127.0.0.1", 8765)),
    ("9000", (DEFAULT_HOST, 9000)),
    ("[::1]:0", ("::1", 0)),
    ("0.0.0.0:8765", ("0.0.0.0", 8765)),
])
def test_live_address_is_host_and_port_on_this_machine_unless_named(given, expected):
    assert parse_address(given) == expected


@pytest.mark.parametrize("bad", ["localhost", "host:99999", ":8765", "a:b:1", ""])
def test_a_live_address_that_does_not_parse_is_one_line(bad):
    with pytest.raises(ValueError, match="is no HOST:PORT"):
        parse_address(bad)
    result = CliRunner().invoke(cli, ["eval", "--live", bad])
    assert result.exit_code == 2 and len(result.stderr.strip().splitlines()) == 1


def test_rate_goes_with_live(tmp_path):
    result = CliRunner().invoke(cli, ["replay", str(tmp_path / "any.mcap"), "--rate", "2"])
    assert result.exit_code == 2 and "--rate sets the pace of --live" in result.stderr


def test_every_log_topic_is_served_with_the_log_schema(live):
    client = FoxgloveClient(live.url)
    wait_for(lambda: set(client.channels) == set(TOPICS), "every topic advertised")
    for topic, schema in SCHEMAS.items():
        channel = client.channels[topic]
        assert (channel["schemaName"], channel["schemaEncoding"], channel["encoding"]) == (
            schema.name, schema.encoding, schema.message_encoding)
    client.close()
