"""Behaviour of the pursuer Q-networks: shapes, masking, permutation invariance,
dropout, registry, and the published TERL size."""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn

from terl_rt.policy.models import MODELS
from training.export import example_inputs
from training.config import Config
from training.networks import build_network, fixed_fractions, network_classes, network_from_config
from training.networks.encoders import (
    TargetSelection,
    masked_max,
    masked_mean,
    masked_softmax,
)
from training.networks.terl import MaskedSelfAttention, ValidTokens, attention_bias

ALL_MODELS = sorted(network_classes())
TARGET_SELECTION_MODELS = ["terl", "terl-no-re"]
TRANSFORMER_MODELS = ["terl", "terl-no-ts"]
NAMES = ("ego", "teammates", "evaders", "obstacles", "mask")


def small_network(name: str, train: bool = False) -> nn.Module:
    """A seeded H=32, L=2, h=4 network in eval mode unless `train`."""
    torch.manual_seed(0)
    return build_network(name, hidden=32, layers=2, heads=4).train(train)


def observation(
    batch: int = 4, teammates: int = 5, evaders: int = 8, obstacles: int = 5, **kwargs
) -> dict[str, torch.Tensor]:
    return example_inputs(batch, teammates, evaders, obstacles, **kwargs)


def run(model: nn.Module, inputs: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor | None]:
    """(q_values [B, 9], target_weights [B, E] or None) without gradients."""
    with torch.no_grad():
        return model.policy_outputs(*(inputs[name] for name in NAMES))


def test_each_network_class_is_registered_under_a_name_of_the_runtimes_registry():
    assert list(network_classes()) == list(MODELS)
    for name, cls in network_classes().items():
        assert cls.model_name == name and cls.has_transformer == MODELS[name].transformer


def test_a_configs_network_part_builds_its_network_with_its_dropout():
    model = network_from_config(Config.of(model="terl", hidden=16, layers=1, heads=2, dropout=0.25).network)
    assert model.config == {"name": "terl", "hidden": 16, "layers": 1, "heads": 2}
    assert {module.p for module in model.modules() if isinstance(module, nn.Dropout)} == {0.25}


@pytest.mark.parametrize("name", ALL_MODELS)
def test_forward_returns_quantiles_for_each_fraction_and_action(name):
    model = small_network(name)
    inputs = observation(batch=3, evaders=8, partial_mask=True)
    taus = torch.rand(3, 8)
    output = model(*(inputs[n] for n in NAMES), taus=taus)
    # dqn returns its Q-values as a single "quantile".
    assert output.quantiles.shape == ((3, 1, 9) if name == "dqn" else (3, 8, 9))
    if model.has_target_selection:
        assert output.target_weights.shape == (3, 8)
    else:
        assert output.target_weights is None


@pytest.mark.parametrize("name", ALL_MODELS)
@pytest.mark.parametrize("teammates, evaders, obstacles", [(5, 8, 5), (5, 14, 5), (3, 20, 7)])
def test_q_values_have_one_value_per_action_for_any_slot_counts(name, teammates, evaders, obstacles):
    model = small_network(name)
    q_values, target_weights = run(model, observation(2, teammates, evaders, obstacles, partial_mask=True))
    assert q_values.shape == (2, 9)
    assert torch.isfinite(q_values).all()
    if model.has_target_selection:
        assert target_weights.shape == (2, evaders)


def test_q_values_are_mean_of_quantiles_at_fixed_fractions():
    model = small_network("terl")
    inputs = observation()
    taus = torch.tensor([[(k + 0.5) / 32 for k in range(32)]]).expand(4, 32)
    with torch.no_grad():
        quantiles = model(*(inputs[n] for n in NAMES), taus=taus).quantiles
    torch.testing.assert_close(model.q_values(*(inputs[n] for n in NAMES)), quantiles.mean(dim=1))
    torch.testing.assert_close(fixed_fractions(), taus[:1])


@pytest.mark.parametrize("name", ALL_MODELS)
def test_padding_content_does_not_change_outputs(name):
    model = small_network(name)
    inputs = observation(batch=5, partial_mask=True)
    garbage = {key: value.clone() for key, value in inputs.items()}
    slots = {"teammates": (1, 6), "evaders": (6, 14), "obstacles": (14, 19)}
    for group, (start, stop) in slots.items():
        padded = ~inputs["mask"][:, start:stop]
        noise = 1e3 * torch.randn_like(garbage[group])
        garbage[group][padded] = noise[padded]
    garbage["evaders"][2, 0, 0] = float("nan")  # row 2 has only its ego present
    for clean, dirty in zip(run(model, inputs), run(model, garbage)):
        if clean is not None:
            torch.testing.assert_close(clean, dirty)


@pytest.mark.parametrize("name", ALL_MODELS)
def test_padded_slots_count_for_nothing(name):
    # The same observation with 2 teammates, 3 evaders and 4 obstacles, once padded
    # to 5/8/5 slots and once with exactly those slots, must give the same answer.
    model = small_network(name)
    padded = observation(batch=3)
    padded["mask"][:, 1 + 2 : 1 + 5] = False
    padded["mask"][:, 6 + 3 : 6 + 8] = False
    padded["mask"][:, 14 + 4 :] = False
    exact = {
        "ego": padded["ego"],
        "teammates": padded["teammates"][:, :2],
        "evaders": padded["evaders"][:, :3],
        "obstacles": padded["obstacles"][:, :4],
        "mask": torch.ones(3, 1 + 2 + 3 + 4, dtype=torch.bool),
    }
    q_padded, weights_padded = run(model, padded)
    q_exact, weights_exact = run(model, exact)
    torch.testing.assert_close(q_padded, q_exact, atol=1e-5, rtol=1e-5)
    if model.has_target_selection:
        torch.testing.assert_close(weights_padded[:, :3], weights_exact, atol=1e-6, rtol=1e-5)
        assert (weights_padded[:, 3:] == 0).all()


@pytest.mark.parametrize("name", ALL_MODELS)
def test_q_values_invariant_to_token_order_within_each_group(name):
    model = small_network(name)
    inputs = observation(batch=4, partial_mask=True)
    generator = torch.Generator().manual_seed(1)
    order = {
        "teammates": torch.randperm(5, generator=generator),
        "evaders": torch.randperm(8, generator=generator),
        "obstacles": torch.randperm(5, generator=generator),
    }
    mask_columns = torch.cat(
        [torch.tensor([0]), 1 + order["teammates"], 6 + order["evaders"], 14 + order["obstacles"]]
    )
    shuffled = {group: inputs[group][:, index] for group, index in order.items()}
    shuffled["ego"] = inputs["ego"]
    shuffled["mask"] = inputs["mask"][:, mask_columns]
    q_values, weights = run(model, inputs)
    q_shuffled, weights_shuffled = run(model, shuffled)
    torch.testing.assert_close(q_shuffled, q_values, atol=1e-5, rtol=1e-5)
    if model.has_target_selection:
        torch.testing.assert_close(weights_shuffled, weights[:, order["evaders"]], atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("name", TARGET_SELECTION_MODELS)
def test_target_weights_sum_to_one_over_valid_evaders_and_zero_on_padding(name):
    model = small_network(name)
    inputs = observation(batch=6, partial_mask=True)
    _, weights = run(model, inputs)
    evader_mask = inputs["mask"][:, 6:14]
    assert (weights[~evader_mask] == 0).all()
    has_evader = evader_mask.any(dim=1)
    torch.testing.assert_close(weights[has_evader].sum(dim=1), torch.ones(int(has_evader.sum())))


@pytest.mark.parametrize("name", TARGET_SELECTION_MODELS)
def test_row_without_valid_evader_gets_zero_weights_and_finite_q_values(name):
    model = small_network(name)
    inputs = observation(batch=3, partial_mask=True)
    inputs["mask"][:, 6:14] = False
    q_values, weights = run(model, inputs)
    assert (weights == 0).all()
    assert torch.isfinite(q_values).all()


def test_target_selection_without_valid_evader_adds_nothing_to_context():
    # z = LayerNorm(c + w . V) with w = 0 must be exactly LayerNorm(c).
    torch.manual_seed(0)
    selection = TargetSelection(16)
    context = torch.randn(2, 16)
    z, weights = selection(context, torch.randn(2, 5, 16), torch.zeros(2, 5, dtype=torch.bool))
    assert (weights == 0).all()
    torch.testing.assert_close(z, selection.norm(context))


@pytest.mark.parametrize("name", TRANSFORMER_MODELS)
def test_eval_mode_gives_deterministic_output(name):
    model = small_network(name)
    inputs = observation(partial_mask=True)
    first, second = run(model, inputs)[0], run(model, inputs)[0]
    assert torch.equal(first, second)


def test_train_mode_applies_dropout():
    model = small_network("terl", train=True)
    inputs = observation()
    torch.manual_seed(1)
    first = run(model, inputs)[0]
    torch.manual_seed(2)
    second = run(model, inputs)[0]
    assert not torch.allclose(first, second)


@pytest.mark.parametrize("name", ALL_MODELS)
def test_every_parameter_receives_gradient(name):
    model = small_network(name, train=True)
    inputs = observation(partial_mask=True)
    output = model(*(inputs[n] for n in NAMES), taus=torch.rand(4, 8))
    output.quantiles.sum().backward()
    missing = [key for key, p in model.named_parameters() if p.grad is None or not p.grad.any()]
    assert missing == []


def test_default_terl_has_published_parameter_count():
    # H=256, h=8, L=4. Encoders 8,960; type embedding 1,024; 4 layers x 789,760
    # (attention 263,168, feed-forward 525,568, two LayerNorms 1,024);
    # Linear(2H->H) 131,328; target selection 197,888; IQN head 85,257.
    # Total 3,583,497: the paper's "3.58 M" (no final LayerNorm, as in the published code).
    count = sum(p.numel() for p in build_network("terl").parameters())
    assert count == 3_583_497
    assert math.isclose(count, 3.58e6, rel_tol=0.005)


@pytest.mark.parametrize("name", ALL_MODELS)
def test_build_network_rebuilds_model_from_its_config(name):
    model = small_network(name)
    rebuilt = build_network(**model.config).eval()
    rebuilt.load_state_dict(model.state_dict())
    inputs = observation(partial_mask=True)
    assert torch.equal(run(model, inputs)[0], run(rebuilt, inputs)[0])
    assert model.config["name"] == name


@pytest.mark.parametrize("name", ALL_MODELS)
def test_a_body_records_layers_and_heads_when_its_class_says_it_has_a_transformer(name):
    has_transformer = network_classes()[name].has_transformer
    assert has_transformer == (name in TRANSFORMER_MODELS)
    config = small_network(name).config
    assert (config["layers"], config["heads"]) == ((2, 4) if has_transformer else (0, 0))


def test_build_network_rejects_unknown_name():
    with pytest.raises(ValueError, match="unknown network 'transformer'"):
        build_network("transformer", 32, 2, 4)


def test_mask_of_wrong_width_is_refused():
    model = small_network("terl")
    inputs = observation()
    inputs["mask"] = inputs["mask"][:, :-1]
    with pytest.raises(ValueError, match="mask: expected bool"):
        run(model, inputs)


def test_dqn_ignores_quantile_fractions():
    model = small_network("dqn")
    inputs = observation()
    with torch.no_grad():
        without = model(*(inputs[n] for n in NAMES)).quantiles
        with_taus = model(*(inputs[n] for n in NAMES), taus=torch.rand(4, 8)).quantiles
    assert torch.equal(without, with_taus)


def test_iqn_head_refuses_missing_fractions():
    model = small_network("iqn")
    inputs = observation()
    with pytest.raises(ValueError, match="needs quantile fractions"):
        model(*(inputs[n] for n in NAMES))


def test_masked_max_ignores_padding():
    tokens = torch.tensor([[[1.0, 5.0], [9.0, -1.0], [3.0, 2.0]]] * 2)
    mask = torch.tensor([[True, False, True], [False, False, False]])
    # Row 0: max of (1, 5) and (3, 2) = (3, 5); the padded (9, -1) is ignored.
    # Row 1: nothing valid -> 0.
    torch.testing.assert_close(masked_max(tokens, mask), torch.tensor([[3.0, 5.0], [0.0, 0.0]]))


def test_masked_mean_ignores_padding():
    tokens = torch.tensor([[[1.0, 5.0], [9.0, -1.0], [3.0, 2.0]]] * 2)
    mask = torch.tensor([[True, False, True], [False, False, False]])
    # Row 0: ((1, 5) + (3, 2)) / 2 = (2, 3.5). Row 1: nothing valid -> 0.
    torch.testing.assert_close(masked_mean(tokens, mask), torch.tensor([[2.0, 3.5], [0.0, 0.0]]))


def test_masked_softmax_renormalises_over_valid_entries():
    scores = torch.tensor([[0.0, math.log(3.0), 100.0], [1.0, 2.0, 3.0]])
    mask = torch.tensor([[True, True, False], [False, False, False]])
    # Row 0: exp(0) : exp(ln 3) = 1 : 3 -> 0.25, 0.75; the masked 100 gets 0.
    expected = torch.tensor([[0.25, 0.75, 0.0], [0.0, 0.0, 0.0]])
    torch.testing.assert_close(masked_softmax(scores, mask), expected)


def test_self_attention_matches_torch_multihead_attention():
    torch.manual_seed(0)
    attention = MaskedSelfAttention(16, 4).eval()
    reference = nn.MultiheadAttention(16, 4, batch_first=True).eval()
    with torch.no_grad():
        reference.in_proj_weight.copy_(attention.in_proj.weight)
        reference.in_proj_bias.copy_(attention.in_proj.bias)
        reference.out_proj.weight.copy_(attention.out_proj.weight)
        reference.out_proj.bias.copy_(attention.out_proj.bias)
        tokens = torch.randn(3, 7, 16)
        mask = torch.rand(3, 7) < 0.5
        mask[:, 0] = True
        expected, _ = reference(tokens, tokens, tokens, key_padding_mask=~mask, need_weights=False)
        valid = ValidTokens(mask)
        attended = attention(valid.gather(tokens.flatten(0, 1)), attention_bias(mask), valid)
        torch.testing.assert_close(attended, expected[mask], atol=1e-5, rtol=1e-5)


def test_valid_tokens_gather_the_valid_rows_in_order_and_spread_them_back_with_zeros_at_padding():
    mask = torch.tensor([[True, False, True], [True, True, False]])
    rows = torch.arange(6, dtype=torch.float32).reshape(6, 1) + 1
    valid = ValidTokens(mask)
    gathered = valid.gather(rows)
    assert gathered.squeeze(1).tolist() == [1.0, 3.0, 4.0, 5.0]
    assert valid.spread(gathered).squeeze(1).tolist() == [1.0, 0.0, 3.0, 4.0, 5.0, 0.0]


def test_attention_bias_gives_padded_keys_zero_weight_and_valid_keys_their_softmax():
    scores = torch.tensor([[[[0.0, math.log(3.0), 100.0]] * 3]])
    mask = torch.tensor([[True, True, False]])
    # exp(0) : exp(ln 3) = 1 : 3 -> 0.25, 0.75 on every query; the padded 100 gets exactly 0.
    weights = torch.softmax(scores + attention_bias(mask), dim=-1)
    torch.testing.assert_close(weights, torch.tensor([[[[0.25, 0.75, 0.0]] * 3]]))
    assert torch.equal(weights[..., 2], torch.zeros(1, 1, 3))
