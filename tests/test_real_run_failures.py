"""The failures that real runs meet end in one clear line, or are refused by name (issue 41):
policies that fail while running, metadata that breaks readers, APIs that would coerce,
logs whose end a crash zeroed, work whose cost is said before it starts."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from mcap.writer import Writer
from one_line import assert_one_error, invoke
from onnx_models import random_observation, write_constant_policy, write_failing_policy, write_test_policy
from processes import wait_for_log

from terl_rt.logs.format import EpisodeLogError, decode
from terl_rt.logs.reader import EpisodeLogReader
from terl_rt.logs.scan import ZEROED_TAIL_BYTES
from terl_rt.logs.resimulate import verify
from terl_rt.policy.contract import ContractError
from terl_rt.policy.embed import decide
from terl_rt.policy.onnx_policy import OnnxPolicy, PolicyRunError
from terl_rt.sim.evader import ConstantEvader
from terl_rt.sim.scenario import Scenario, ScenarioError
from terl_rt.sim.world import World

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(scope="module")
def files(logged_eval, tmp_path_factory) -> dict:
    """The shared logged eval's policy and log, a policy that fails inside onnxruntime and a folder for outputs."""
    folder = tmp_path_factory.mktemp("failures")
    return {**logged_eval, "folder": folder, "failing": write_failing_policy(folder / "failing.onnx")}


# --- a policy that loads but fails inside onnxruntime -------------------------------------


def test_a_policy_failing_inside_onnxruntime_names_the_policy_the_batch_and_the_node(files):
    policy = OnnxPolicy(files["failing"])  # it loads: the contract's checks pass
    with pytest.raises(PolicyRunError) as caught:
        policy.act(random_observation((4,)))
    message = str(caught.value)
    assert str(files["failing"]) in message and "batch of 4 rows" in message and "Reshape" in message
    assert "\n" not in message and "onnxruntime_src" not in message


def test_an_allocation_onnxruntime_cannot_make_says_the_policy_ran_out_of_memory(files, monkeypatch):
    policy = OnnxPolicy(files["policy"])

    class Session:  # what onnxruntime raises when its arena cannot grow
        def run(self, names, feed):
            raise RuntimeError("[ONNXRuntimeError] : 6 : RUNTIME_EXCEPTION : Non-zero status code returned while "
                               "running MatMul node. Name:'' Status Message: Failed to allocate memory for requested "
                               "buffer of size 68719476736")

    monkeypatch.setattr(policy, "_session", Session())
    with pytest.raises(PolicyRunError, match=r"ran out of memory inside onnxruntime in a MatMul node on a batch of 3 rows"):
        policy.act(random_observation((3,)))


@pytest.mark.parametrize("command", [
    ("eval", "--scenario", "small-11", "--episodes", "1"),
    ("sweep", "--scenario", "small-11", "--episodes", "1", "--out", "{folder}/sweep"),
    ("report", "--scenario", "small-11", "--episodes", "1", "--out", "{folder}/report"),
    ("bench", "policy", "--scenario", "small-11", "--batch", "4", "--calls", "2"),
])
def test_a_policy_failing_while_it_runs_is_one_error_line(files, command):
    if command[0] == "report":
        pytest.importorskip("matplotlib")
    args = [arg.format(**files) for arg in command]
    result = invoke(*args[: 2 if command[0] == "bench" else 1], "--policy", files["failing"],
                    *args[2 if command[0] == "bench" else 1:])
    assert_one_error(result, "failing.onnx", "inside onnxruntime")


def test_decide_raises_the_policy_s_failure_as_a_contract_error(files):
    class Batched:  # decide's one row, evaluated as four: what a Reshape bug does
        name = "batched"

        def __init__(self, policy):
            self.policy = policy

        def evaluate(self, observation):
            return self.policy.evaluate({key: np.repeat(value, 4, 0) for key, value in observation.as_inputs().items()})

    with pytest.raises(ContractError, match="inside onnxruntime"):
        decide(Batched(OnnxPolicy(files["failing"])), (10.0, 10.0), 0.0, (0.0, 0.0))


# --- the embedding API checks outputs and inputs as the CLI does -------------------------


def test_decide_refuses_a_policy_that_outputs_nan(tmp_path):
    policy = OnnxPolicy(write_constant_policy(tmp_path / "nan.onnx", [math.nan] + [0.0] * 8))
    with pytest.raises(ContractError, match="non-finite q_values"):
        decide(policy, (10.0, 10.0), 0.0, (0.0, 0.0))


@pytest.mark.parametrize("heading", ["0.3", b"1", True, None, [0.1], math.nan, 1e300])
def test_decide_refuses_a_heading_that_is_not_a_number_by_name(files, heading):
    with pytest.raises(ValueError, match="ego_heading"):
        decide(OnnxPolicy(files["policy"]), (10.0, 10.0), heading, (0.0, 0.0))


@SETTINGS
@given(st.one_of(st.floats(-1e4, 1e4), st.integers(-100, 100), st.text(max_size=4), st.none(), st.booleans()))
def test_decide_takes_any_heading_or_refuses_it_by_name(heading):
    policy = _shared_policy()
    try:
        decision = decide(policy, (10.0, 10.0), heading, (0.0, 0.0))
    except ValueError as error:
        assert "ego_heading" in str(error)
        return
    assert 0 <= decision.action < 9 and np.isfinite(decision.q_values).all()


_POLICY: list[OnnxPolicy] = []


def _shared_policy() -> OnnxPolicy:
    """One linear test policy for every hypothesis example (written once, to a temporary folder)."""
    if not _POLICY:
        import tempfile

        _POLICY.append(OnnxPolicy(write_test_policy(Path(tempfile.mkdtemp()) / "linear.onnx")))
    return _POLICY[0]


# --- the PettingZoo env refuses what it would coerce -------------------------------------


def parallel_env(*args, **kwargs):
    pytest.importorskip("pettingzoo")
    from terl_rt.envs import parallel_env as make

    return make(*args, **kwargs)


@pytest.mark.parametrize("action", [2.5, "3", True, None, np.array([1, 2]), 2**70, -1, 9, np.float64(2.0)])
def test_an_env_action_that_is_not_an_index_is_refused_naming_the_agent_and_value(action):
    env = parallel_env("small-11")
    env.reset(seed=0)
    actions = {agent: 0 for agent in env.agents}
    actions["pursuer_0"] = action
    with pytest.raises((TypeError, ValueError), match="pursuer_0") as caught:
        env.step(actions)
    assert repr(action)[:20] in str(caught.value) or str(action)[:20] in str(caught.value)
    assert env.world.state.steps[0] == 0  # nothing moved


@SETTINGS
@given(st.one_of(st.integers(-(2**80), 2**80), st.floats(allow_nan=True), st.text(max_size=3), st.none(),
                 st.booleans(), st.lists(st.integers(0, 8), max_size=2)))
def test_any_env_action_steps_or_is_refused_by_name(action):
    env = parallel_env("small-11", max_steps=3)
    env.reset(seed=0)
    try:
        env.step({agent: action for agent in env.agents})
    except (TypeError, ValueError) as error:
        assert "pursuer_" in str(error)
        return
    assert isinstance(action, int) and not isinstance(action, bool) and 0 <= action < 9


@SETTINGS
@given(st.one_of(st.integers(-5, 2**64), st.floats(allow_nan=True), st.text(max_size=3), st.booleans()))
def test_any_env_seed_resets_or_is_refused_by_name(seed):
    env = parallel_env("small-11")
    try:
        env.reset(seed=seed)
    except (TypeError, ValueError) as error:
        assert "seed" in str(error)
        return
    assert isinstance(seed, int) and not isinstance(seed, bool) and seed >= 0


@pytest.mark.parametrize("kwargs, words", [
    ({"scenario": 42}, "scenario"),
    ({"scenario": "small-11", "render_size": 100_000}, "render_size"),
    ({"scenario": "small-11", "render_size": 10}, "render_size"),
    ({"scenario": "small-11", "render_size": 480.0}, "render_size"),
    ({"scenario": "small-11", "max_steps": 2.5}, "max_steps"),
])
def test_env_arguments_that_would_be_coerced_are_refused_by_name(kwargs, words):
    with pytest.raises((TypeError, ValueError), match=words):
        parallel_env(**kwargs)


# --- the world refuses a bad evader policy; scenarios refuse what cannot be printed -----


@pytest.mark.parametrize("action", [15, -1])  # 15 evader actions (world.md section 2)
def test_an_evader_policy_s_bad_action_is_refused_naming_the_policy(action):
    world = World(Scenario.preset("small-11"), num_envs=1, seed=0, evader_policy=ConstantEvader(action))
    world.reset()
    with pytest.raises(ValueError, match="evader policy's actions.*ConstantEvader"):
        world.step(np.zeros((1, 11), np.int64))


def test_an_evader_policy_returning_floats_is_refused_not_truncated():
    class Drifting:
        def act(self, state, geometry, params, arena):
            return np.full(state.evader_active.shape, 2.5)

    world = World(Scenario.preset("small-11"), num_envs=1, seed=0, evader_policy=Drifting())
    world.reset()
    with pytest.raises(ValueError, match="integer action indices"):
        world.step(np.zeros((1, 11), np.int64))


@pytest.mark.parametrize("name", ["a\ud800b", "tab\tname", "line\nbreak", "\x00"])
def test_a_scenario_name_that_cannot_be_printed_is_refused(name):
    data = Scenario.preset("small-11").to_dict() | {"name": name}
    with pytest.raises(ScenarioError, match="name: must be printable"):
        Scenario.from_dict(data)
    with pytest.raises(ScenarioError, match="name"):
        Scenario.from_dict(json.loads(json.dumps(data)))


def test_a_scenario_file_named_with_an_unpaired_surrogate_is_one_line_before_any_episode(files, tmp_path):
    path = tmp_path / "surrogate.json"
    path.write_text(json.dumps(Scenario.preset("small-11").to_dict() | {"name": "x\ud800"}))
    result = invoke("eval", "--policy", files["policy"], "--scenario-file", path, "--csv", tmp_path / "e.csv")
    assert_one_error(result, "name")
    assert not (tmp_path / "e.csv").exists()


@pytest.mark.parametrize("heading", [1e300, -1e300, 1001.0])
def test_an_initial_state_heading_beyond_a_thousand_radians_is_refused(heading):
    data = Scenario.preset("small-11").to_dict()
    scenario = Scenario.from_dict(data)
    rows = placed_rows(scenario)
    rows["pursuers"][0][2] = heading
    with pytest.raises(ScenarioError, match=r"initial_state.pursuers\[0\]: heading"):
        Scenario.from_dict(data | {"initial_state": rows})


def placed_rows(scenario: Scenario) -> dict:
    """An initial_state that follows the world's rules: the placement of seed 0."""
    world = World(scenario, num_envs=1, seed=0)
    world.reset()
    s = world.state
    return {
        "pursuers": np.column_stack([s.pursuer_xy[0], s.pursuer_theta[0], s.pursuer_speed[0]]).tolist(),
        "evaders": np.column_stack([s.evader_xy[0], s.evader_theta[0], s.evader_speed[0]]).tolist(),
        "obstacles": np.column_stack([s.obstacle_xy[0], s.obstacle_r[0]]).tolist(),
        "vortices": np.column_stack([s.vortex_xy[0], s.vortex_gamma[0], s.vortex_clockwise[0]]).tolist(),
    }


# --- metadata that would break readers ----------------------------------------------------


def _policy_with_metadata(path, key: str, value: bytes):
    """The linear test policy with metadata `key` set to the raw bytes `value`."""
    import onnx

    model = onnx.load(str(write_test_policy(path)))
    placeholder = "X" * len(value)
    for prop in model.metadata_props:
        if prop.key == key:
            prop.value = placeholder
    path.write_bytes(model.SerializeToString().replace(placeholder.encode(), value))
    return path


@pytest.mark.parametrize("key, value, words", [
    ("terl.trained_on", b"\xff\xfe bad", "not UTF-8"),
    ("terl.model", b"lin\xffear", "not UTF-8"),
    ("terl.pursuer_actions", b"[" * 100_000, "terl.pursuer_actions"),
])
@pytest.mark.parametrize("command", ["info", "eval"])
def test_policy_metadata_that_is_not_text_or_nests_too_deep_is_one_line(tmp_path, key, value, words, command):
    path = _policy_with_metadata(tmp_path / "odd.onnx", key, value)
    args = ("info", path) if command == "info" else ("eval", "--policy", path, "--episodes", "1", "--max-steps", "2")
    result = invoke(*args)
    assert_one_error(result, str(path), words)


METADATA_KEYS = ["terl.contract", "terl.model", "terl.hidden", "terl.pursuer_actions", "terl.trained_on"]


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(key=st.sampled_from(METADATA_KEYS), value=st.one_of(
    st.binary(min_size=1, max_size=24), st.text(min_size=1, max_size=24).map(lambda text: text.encode("utf-8", "surrogatepass")),
    st.integers(1, 50_000).map(lambda depth: b"[" * depth),
))
@example(key="terl.contract", value=b"\x00\n\x00")  # found by hypothesis: a line break in a quoted value
def test_any_policy_metadata_value_loads_or_is_a_contract_error(tmp_path, key, value):
    try:
        OnnxPolicy(_policy_with_metadata(tmp_path / "any.onnx", key, value))
    except ContractError as error:
        assert "\n" not in str(error).strip()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(st.binary(min_size=11, max_size=11))
def test_any_bytes_in_a_log_s_metadata_read_or_are_an_episode_log_error(files, tmp_path, value):
    damaged = tmp_path / "damaged.mcap"
    _rewrite(files["log"], b"linear-test", value, damaged)
    try:
        reader = EpisodeLogReader(damaged)
    except EpisodeLogError as error:
        assert str(damaged) in str(error)
        return
    assert reader.policy["name"] == value.decode()


def _rewrite(log, old: bytes, new: bytes, to) -> None:
    data = log.read_bytes()
    assert len(old) == len(new) and old in data
    to.write_bytes(data.replace(old, new, 1))


@pytest.mark.parametrize("command", ["replay", "verify", "render"])
def test_a_log_metadata_record_that_is_not_utf8_is_one_line(files, tmp_path, command):
    bad = tmp_path / "bad.mcap"
    _rewrite(files["log"], b"linear-test", b"linear\xfftest", bad)
    args = {"replay": ("replay", bad), "verify": ("replay", bad, "--verify"),
            "render": ("render", bad, "-o", tmp_path / "x.png")}[command]
    assert_one_error(invoke(*args), str(bad), "not UTF-8")


def test_a_log_metadata_value_nested_too_deep_is_one_line(tmp_path):
    path = tmp_path / "deep.mcap"
    with open(path, "wb") as handle:
        writer = Writer(handle)
        writer.start()
        writer.add_metadata("terl.log", {
            "format": "terl-rt episode log", "version": "2", "policy": "p", "policy_sha256": "0",
            "policy_metadata": "[" * 100_000,
        })
        writer.finish()
    with pytest.raises(EpisodeLogError) as caught:
        EpisodeLogReader(path)
    assert str(path) in str(caught.value)
    assert_one_error(invoke("replay", path), str(path))


@SETTINGS
@given(st.one_of(st.binary(max_size=40), st.text(max_size=40).map(str.encode),
                 st.integers(1, 3000).map(lambda depth: b"[" * depth + b"]" * depth)))
def test_any_log_record_text_decodes_or_is_a_value_error(data):
    try:
        decode(data)
    except ValueError:
        pass


# --- a log whose end a crash zeroed -------------------------------------------------------


@pytest.mark.parametrize("zeroed", [ZEROED_TAIL_BYTES, 4096, 20_000])
def test_a_log_whose_last_kilobytes_are_zeros_reads_to_its_last_complete_step(files, tmp_path, zeroed):
    data = bytearray(files["log"].read_bytes())
    data[-zeroed:] = bytes(zeroed)
    crashed = tmp_path / "crashed.mcap"
    crashed.write_bytes(bytes(data))
    reader = EpisodeLogReader(crashed)
    assert reader.truncated and "zeros" in reader.problem and reader.episodes[0].steps == 30
    assert verify(crashed, 0).ok
    result = invoke("replay", crashed)
    assert result.exit_code == 0 and "zeros" in result.output


# --- work without end in sight says what it will cost -------------------------------------


def test_bench_sim_says_what_it_will_run_and_shows_progress_on_a_terminal_only():
    result = invoke("bench", "sim", "--scenario", "small-11", "--envs", "2", "--steps", "3")
    assert result.exit_code == 0, result.output
    assert "placing 2 world(s) of small-11 (11 pursuers each), then 5 untimed and 3 timed batch steps" in result.stderr
    assert "bench sim" not in result.stderr and "env-steps/s" in result.stdout  # the runner's stderr is no terminal


# --- stopping a run of one process (the workers' part comes with the batched evaluator) --


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_or_sighup_of_a_logged_run_keeps_its_complete_steps(files, tmp_path, signum):
    log = tmp_path / "stopped.mcap"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    process = subprocess.Popen(
        [sys.executable, "-m", "terl_rt", "eval", "--policy", str(files["policy"]), "--scenario", "small-11",
         "--episodes", "6", "--max-steps", "400", "--log", str(log)],
        cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        preexec_fn=lambda: signal.signal(signum, signal.SIG_DFL),  # under nohup, SIGHUP comes ignored
    )
    try:
        wait_for_log(process, log, size=60_000)
        process.send_signal(signum)
        assert process.wait(timeout=30) != 0
    finally:
        process.kill()
    reader = EpisodeLogReader(log)
    assert reader.truncated and reader.episodes[0].steps > 0
    assert verify(log, 0).ok
