"""S networks of one architecture as one module: seeds trained together (policy.md section 2).

`stack_network` turns a `QNetwork` into the same module tree whose parametrised layers hold a
leading seed axis: every `nn.Linear` becomes a `SeedLinear` (one batched product for all S
networks), every `nn.LayerNorm` a `SeedLayerNorm`, the `TypeEmbedding` a `SeedTypeEmbedding`.
Every other operation of the networks works row by row, so the stacked module takes the
inputs of S networks concatenated seed-major along the batch axis ([S * B, ...], seed s's rows
at s * B .. s * B + B - 1) and returns their outputs the same way: the architecture is written
once, in training/networks, and the stacked form is only its layers swapped.

The weights are views of one flat tensor [S, P] (P: one network's parameter count, in
`named_parameters` order), so the optimizer and the gradient clip of all S networks are a few
calls on flat tensors, and `seed_network` gives each seed a plain `QNetwork` over its row of
it (acting, snapshots, checkpoints and export see an ordinary network that follows every update).
"""

from __future__ import annotations

import copy

import torch
from torch import nn
from torch.nn import functional

from training.networks.encoders import QNetwork
from training.networks.terl import RelationExtractor, TypeEmbedding

TOKEN_BUCKET = 128
"""Rows each seed's valid tokens are padded to a multiple of in a stacked forward
(training.networks.terl.ValidTokens): shapes repeat across updates at a small padding cost."""


def by_seed(rows: torch.Tensor, seeds: int) -> torch.Tensor:
    """Seed-major rows [S * X, ..., W] -> [S, X * ..., W]."""
    return rows.reshape(seeds, -1, rows.shape[-1])


class SeedLinear(nn.Module):
    """S `nn.Linear` layers of one shape: weight [S, out, in], bias [S, out]; [S * X, ..., in] -> [S * X, ..., out]."""

    def __init__(self, weight: nn.Parameter, bias: nn.Parameter | None) -> None:
        super().__init__()
        self.weight = weight
        self.bias = bias

    def forward(self, rows: torch.Tensor) -> torch.Tensor:
        seeds, width = self.weight.shape[0], self.weight.shape[1]
        grouped = by_seed(rows, seeds)
        if self.bias is None:
            product = torch.bmm(grouped, self.weight.transpose(1, 2))
        else:
            product = torch.baddbmm(self.bias.unsqueeze(1), grouped, self.weight.transpose(1, 2))
        return product.reshape(*rows.shape[:-1], width)


class SeedLayerNorm(nn.Module):
    """S `nn.LayerNorm` layers over the last axis: weight and bias [S, H]; [S * X, ..., H] -> the same shape."""

    def __init__(self, weight: nn.Parameter, bias: nn.Parameter, eps: float) -> None:
        super().__init__()
        self.weight = weight
        self.bias = bias
        self.eps = eps

    def forward(self, rows: torch.Tensor) -> torch.Tensor:
        normal = functional.layer_norm(rows, rows.shape[-1:], eps=self.eps)
        seeds = self.weight.shape[0]
        scaled = torch.addcmul(self.bias.unsqueeze(1), by_seed(normal, seeds), self.weight.unsqueeze(1))
        return scaled.reshape(rows.shape)


class SeedTypeEmbedding(nn.Module):
    """S type embeddings: weight [S, 4, H]; `add` as `TypeEmbedding.add` on seed-major rows."""

    def __init__(self, weight: nn.Parameter) -> None:
        super().__init__()
        self.weight = weight

    def add(self, tokens: torch.Tensor, kind: int) -> torch.Tensor:
        """tokens [S * B, ..., H] of entity type `kind` plus each seed's row of that type."""
        seeds = self.weight.shape[0]
        return (by_seed(tokens, seeds) + self.weight[:, kind].unsqueeze(1)).reshape(tokens.shape)


def parameter_slices(model: QNetwork) -> dict[str, tuple[int, torch.Size]]:
    """Where each parameter of `model` lies in its flat form: name -> (offset, shape), in
    `named_parameters` order; the last offset plus its size is P."""
    slices, offset = {}, 0
    for name, parameter in model.named_parameters():
        slices[name] = (offset, parameter.shape)
        offset += parameter.numel()
    return slices


def parameter_count(model: QNetwork) -> int:
    """P: the parameters of one network."""
    return sum(parameter.numel() for parameter in model.parameters())


def flat_view(flat: torch.Tensor, offset: int, shape: torch.Size) -> torch.Tensor:
    """The parameter of shape `shape` at `offset` of every seed's row of flat [S, P]: [S, *shape]."""
    size = shape.numel()
    return flat[:, offset : offset + size].view(flat.shape[0], *shape)


def stack_network(template: QNetwork, flat: torch.Tensor, trainable: bool, bucket: int = TOKEN_BUCKET) -> QNetwork:
    """`template`'s architecture for S seeds, its weights views of flat [S, P] (leaf parameters
    that share its storage: what changes `flat` changes them; with `trainable` they take
    gradients). Inputs and outputs are seed-major (see the module docstring); with a
    transformer, each seed's valid tokens are padded to a multiple of `bucket` rows."""
    slices = parameter_slices(template)
    stacked = copy.deepcopy(template)

    def parameter(name: str) -> nn.Parameter:
        return nn.Parameter(flat_view(flat, *slices[name]), requires_grad=trainable)

    for name, module in list(stacked.named_modules()):
        prefix = f"{name}." if name else ""
        if isinstance(module, nn.Linear):
            bias = parameter(prefix + "bias") if module.bias is not None else None
            replacement: nn.Module = SeedLinear(parameter(prefix + "weight"), bias)
        elif isinstance(module, nn.LayerNorm):
            replacement = SeedLayerNorm(parameter(prefix + "weight"), parameter(prefix + "bias"), module.eps)
        elif isinstance(module, TypeEmbedding):
            replacement = SeedTypeEmbedding(parameter(prefix + "weight"))
        else:
            if isinstance(module, RelationExtractor):
                module.seeds, module.token_bucket = flat.shape[0], bucket
            continue
        parent_name, _, child = name.rpartition(".")
        setattr(stacked.get_submodule(parent_name), child, replacement)
    unstacked = [name for name, value in stacked.named_parameters() if value.dim() and value.shape[0] != flat.shape[0]]
    if unstacked or sum(value.numel() for value in stacked.parameters()) != flat.numel():
        raise ValueError(f"stack_network: {type(template).__name__} has parameters outside the stacked layers: {unstacked}")
    return stacked


def seed_network(template: QNetwork, flat: torch.Tensor, seed_index: int) -> QNetwork:
    """A plain copy of `template` whose parameters are views of row `seed_index` of flat [S, P]
    (no gradients): it follows every change of `flat`, and loading a state dict into it writes there."""
    network = copy.deepcopy(template)
    for name, (offset, shape) in parameter_slices(template).items():
        owner, _, attribute = name.rpartition(".")
        view = flat_view(flat, offset, shape)[seed_index]
        setattr(network.get_submodule(owner), attribute, nn.Parameter(view, requires_grad=False))
    return network


def flatten_weights(networks: list[QNetwork]) -> torch.Tensor:
    """The flat weights [S, P] of S networks of one architecture (copies)."""
    return torch.stack([torch.cat([value.detach().reshape(-1) for value in network.parameters()]) for network in networks])
