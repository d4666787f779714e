"""The ONNX export meets the exported-policy contract (policy.md section 3) and matches torch."""

from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch

from terl_rt.sim.actions import PURSUER_ACTIONS
from training import export
from training.__main__ import main
from training.export import ParityError, check_parity, example_inputs, export_onnx, read_metadata
from training.networks import build_network, network_classes

ALL_MODELS = sorted(network_classes())
CALLER_METADATA = {"terl.training_steps": "1000", "terl.trained_on": "small"}


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """exported(name) -> (small eval-mode model, path of its exported policy), exported once per
    module, when a test first asks for it (a parallel run spreads the tests over processes)."""
    folder = tmp_path_factory.mktemp("policies")

    @functools.cache
    def export_model(name: str) -> tuple[torch.nn.Module, Path]:
        torch.manual_seed(0)
        model = build_network(name, hidden=32, layers=2, heads=4).eval()
        return model, export_onnx(model, folder / f"{name}.onnx", CALLER_METADATA)

    return export_model


@pytest.mark.parametrize("name", ALL_MODELS)
def test_exported_policy_matches_torch_on_random_and_masked_inputs(exported, name):
    model, path = exported(name)
    assert check_parity(model, path) <= 1e-4


@pytest.mark.parametrize("name", ["terl", "terl-no-re", "iqn"])
@pytest.mark.parametrize("teammates, evaders, obstacles", [(5, 8, 5), (2, 14, 7), (6, 20, 1)])
def test_exported_policy_runs_with_any_slot_counts(exported, name, teammates, evaders, obstacles):
    _, path = exported(name)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    feed = {
        key: value.numpy()
        for key, value in example_inputs(7, teammates, evaders, obstacles, partial_mask=True).items()
    }
    outputs = dict(zip((o.name for o in session.get_outputs()), session.run(None, feed)))
    assert outputs["q_values"].shape == (7, 9)
    if name != "iqn":
        assert outputs["target_weights"].shape == (7, evaders)


@pytest.mark.parametrize("name", ["terl", "dqn"])
def test_exported_inputs_and_outputs_follow_contract(exported, name):
    model, path = exported(name)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    inputs = {i.name: (i.type, i.shape) for i in session.get_inputs()}
    assert inputs == {
        "ego": ("tensor(float)", ["B", 4]),
        "teammates": ("tensor(float)", ["B", "P", 7]),
        "evaders": ("tensor(float)", ["B", "E", 7]),
        "obstacles": ("tensor(float)", ["B", "O", 5]),
        "mask": ("tensor(bool)", ["B", "1+P+E+O"]),
    }
    outputs = {o.name: (o.type, o.shape) for o in session.get_outputs()}
    expected = {"q_values": ("tensor(float)", ["B", 9])}
    if model.has_target_selection:
        expected["target_weights"] = ("tensor(float)", ["B", "E"])
    if model.distributional:
        expected["quantiles"] = ("tensor(float)", ["B", 32, 9])
    assert outputs == expected


def test_exported_file_passes_onnx_checker(exported):
    _, path = exported("terl")
    onnx.checker.check_model(onnx.load(str(path)), full_check=True)


def test_metadata_holds_contract_keys_and_caller_keys(exported):
    _, path = exported("terl")
    metadata = read_metadata(path)
    assert metadata["terl.contract"] == "1"
    assert metadata["terl.model"] == "terl"
    assert (metadata["terl.hidden"], metadata["terl.layers"], metadata["terl.heads"]) == ("32", "2", "4")
    assert metadata["terl.training_steps"] == "1000"
    assert metadata["terl.trained_on"] == "small"


def test_metadata_records_zero_layers_and_heads_for_bodies_without_transformer(exported):
    _, path = exported("iqn")
    metadata = read_metadata(path)
    assert (metadata["terl.model"], metadata["terl.layers"], metadata["terl.heads"]) == ("iqn", "0", "0")


def test_pursuer_action_table_round_trips_through_metadata(exported):
    _, path = exported("dqn")
    table = np.array(json.loads(read_metadata(path)["terl.pursuer_actions"]))
    np.testing.assert_array_equal(table, PURSUER_ACTIONS)


def test_caller_cannot_override_contract_metadata(tmp_path):
    model = build_network("iqn", hidden=16, layers=0, heads=0)
    with pytest.raises(ValueError, match="terl.model"):
        export_onnx(model, tmp_path / "policy.onnx", {"terl.model": "terl"})


def test_parity_check_fails_when_model_differs_from_file(exported):
    model, path = exported("terl-no-re")
    changed = build_network(**model.config).eval()
    changed.load_state_dict(model.state_dict())
    with torch.no_grad():
        changed.head.out.bias.add_(0.01)
    with pytest.raises(ParityError, match="q_values"):
        check_parity(changed, path)


def test_export_leaves_training_mode_as_it_was(tmp_path):
    model = build_network("terl", hidden=16, layers=1, heads=2).train()
    export_onnx(model, tmp_path / "policy.onnx", {})
    assert model.training


def test_parity_cases_include_real_observations_for_each_paper_evader_slot_count():
    from training.export import parity_cases

    names = [case for case, _ in parity_cases((8, 14, 20))]
    assert "E=8 observations of small-11" in names
    assert "E=14 observations of medium-48" in names
    assert "E=20 observations of large-72" in names


def test_parity_tolerance_is_relative_to_large_outputs():
    # Q-values of a trained policy are in the hundreds: float32 round-off of 1e-4 there is parity.
    # 1000.05 vs 1000: 0.05 / 1000 = 5e-5 <= 1e-4; 0.5002 vs 0.5: 2e-4 / 1 > 1e-4.
    assert export._compare("q", np.array([1000.0, -3.0]), np.array([1000.05, -3.0]), 1e-4) == pytest.approx(5e-5)
    with pytest.raises(ParityError, match="q"):
        export._compare("q", np.array([0.5]), np.array([0.5002]), 1e-4)


def test_export_that_fails_parity_leaves_no_file(tmp_path, monkeypatch):
    def disagree(model, path):
        raise ParityError("q_values: forced disagreement")

    monkeypatch.setattr(export, "check_parity", disagree)
    with pytest.raises(ParityError, match="forced"):
        export_onnx(build_network("iqn", hidden=16, layers=0, heads=0), tmp_path / "policy.onnx", {})
    assert list(tmp_path.iterdir()) == []


def test_transformer_layers_export_as_one_attention_op_each(exported):
    _, path = exported("terl")
    nodes = onnx.load(str(path)).graph.node
    made_by = {output: node.op_type for node in nodes for output in node.output}
    assert [node.op_type for node in nodes].count("Attention") == 2
    # The only Transpose is NonZero's index list ([1, N] -> [N, 1]), never an activation.
    assert all(made_by[node.input[0]] == "NonZero" for node in nodes if node.op_type == "Transpose")


@pytest.mark.parametrize("name", ["terl", "iqn"])
def test_reexported_policy_computes_what_its_source_does(exported, tmp_path, name):
    model, source = exported(name)
    target = export.reexport_onnx(source, tmp_path / "again.onnx")
    assert check_parity(model, target) <= 1e-4
    assert read_metadata(target)[export.META_REEXPORTED_FROM] == hashlib.sha256(source.read_bytes()).hexdigest()


def test_shipped_policy_of_the_older_graph_reexports_with_the_same_outputs(tmp_path):
    # A w/o TS written by the opset-17 exporter (MatMul/Softmax attention): exported/comparison/terl-no-ts.onnx
    # from 308da6c until the comparison's seeds replaced it.
    source = Path(__file__).parents[1] / "data" / "terl-no-ts-opset17.onnx"
    target = export.reexport_onnx(source, tmp_path / "terl-no-ts.onnx")
    feed = {key: value.numpy() for key, value in example_inputs(6, 5, 8, 5, partial_mask=True).items()}
    names = [output.name for output in ort.InferenceSession(str(source)).get_outputs()]
    old, new = (ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(names, feed)
                for path in (source, target))
    for got, expected in zip(new, old):
        np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("name", ALL_MODELS)
def test_a_distributional_head_exports_its_quantiles_and_dqn_none(exported, name):
    model, path = exported(name)
    names = [output.name for output in ort.InferenceSession(str(path)).get_outputs()]
    assert ("quantiles" in names) == model.distributional


def test_with_quantiles_adds_the_output_and_leaves_q_values_bit_for_bit(tmp_path):
    source = Path(__file__).parents[1] / "data" / "terl-no-ts-opset17.onnx"  # an export without quantiles
    target = export.with_quantiles(source, tmp_path / "with.onnx")
    feed = {key: value.numpy() for key, value in example_inputs(6, 5, 8, 5, partial_mask=True).items()}
    before, after = (ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]) for path in (source, target))
    q_values, quantiles = after.run(["q_values", "quantiles"], feed)
    assert np.array_equal(q_values, before.run(["q_values"], feed)[0]) and quantiles.shape == (6, 32, 9)
    assert read_metadata(target) == read_metadata(source)
    with pytest.raises(ValueError, match="has the quantiles output already"):
        export.with_quantiles(target, tmp_path / "twice.onnx")


def test_with_quantiles_refuses_a_network_without_a_distributional_head(exported, tmp_path):
    _, path = exported("dqn")
    with pytest.raises(ValueError, match="no distributional head"):
        export.with_quantiles(path, tmp_path / "dqn.onnx")


def test_export_command_reexports_an_onnx_policy_and_refuses_a_missing_one(exported, tmp_path, capsys):
    _, source = exported("terl")
    assert main(["export", str(source), "-o", str(tmp_path / "again.onnx")]) == 0
    assert read_metadata(tmp_path / "again.onnx")[export.META_REEXPORTED_FROM]
    assert main(["export", str(tmp_path / "missing.onnx"), "-o", str(tmp_path / "out.onnx")]) == 2
    assert "no policy file at" in capsys.readouterr().err


def test_export_names_the_method_and_seed_that_a_report_groups_policies_by(exported, tmp_path, capsys):
    from terl_rt.paper.seed_comparison import policy_identity

    _, source = exported("terl")
    named = tmp_path / "terl-default.onnx"
    assert main(["export", str(source), "--method", "terl-default", "--seed", "7", "-o", str(named)]) == 0
    assert "terl.method terl-default, terl.seed 7;" in capsys.readouterr().out
    assert policy_identity(read_metadata(named)) == ("terl-default", 7)
    assert main(["export", str(source), "--method", "TERL default", "-o", str(tmp_path / "bad.onnx")]) == 2
    assert "'TERL default' is no method name" in capsys.readouterr().err and not (tmp_path / "bad.onnx").exists()
