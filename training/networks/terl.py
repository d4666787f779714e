"""The TERL network (policy.md section 1, paper section IV-B) and its `terl-no-ts` ablation.

Observation embedding -> relation extraction (type embedding + pre-LayerNorm
transformer encoder) -> target selection -> IQN head. Attention is written out
here rather than taken from nn.MultiheadAttention: it has no fast path or
nested-tensor branch that changes what is computed for partly padded rows, and it
exports to ONNX as one `Attention` op a layer (opset 23), with the padding mask
turned into an additive bias once a call and the token-wise layers (LayerNorm, the
projections, the feed-forward) on the valid tokens' rows only, [N, H] with N the valid
tokens of the call (`ValidTokens`): padding is about half of a large-80 step's tokens
and two thirds of a small-15 step's, and none of it reaches a valid token's output.
Only the attention itself sees the padded [B, L] layout.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from training.networks.encoders import (
    EntityEncoders,
    QNetwork,
    TargetSelection,
    masked_max,
    split_mask,
)

DROPOUT = 0.1
"""Dropout probability inside the transformer layers, in training mode only."""
NUM_ENTITY_TYPES = 4
"""Rows of the type embedding: ego 0, teammate 1, evader 2, obstacle 3."""


def attention_bias(mask: torch.Tensor) -> torch.Tensor:
    """Additive attention bias of every layer, made once a call: mask [B, L] bool (true =
    valid key) -> [B, 1, L, L] float32, 0 for valid keys and the lowest float32 for padding.

    Adding it before the softmax gives padded keys a weight of exactly 0 and valid ones the
    same weights, bit for bit, as a softmax over the valid keys alone, as long as every row
    has a valid key: the ego token is always present (policy.md section 3). The [L, L]
    query axis is materialised because ONNX's Attention op takes no broadcast over it.
    """
    length = mask.shape[1]
    lowest = torch.finfo(torch.float32).min
    zero = torch.zeros((), dtype=torch.float32, device=mask.device)
    bias = torch.where(mask, zero, torch.full_like(zero, lowest))
    return bias[:, None, None, :].expand(-1, 1, length, -1)


class ValidTokens:
    """Where the valid tokens of a call lie, made once a call from mask [B, L] bool.

    `gather` keeps the valid rows of [B * L, W] token rows ([N, W], N = valid tokens, in
    row-major order); `spread` puts [N, W] rows back at their places in [B * L, W], with
    zeros at padding. Both are gathers (ONNX Gather), no scatter. No valid token's output
    depends on padding (the attention gives padded keys a weight of exactly 0, the pooling
    and the target selection mask them out), so computing only the valid rows changes no
    output: onnxruntime gave the shipped policy's outputs bit for bit (docs/benchmarks.md).

    Seeds trained together (training.networks.stacked) lay S networks' rows seed-major: the
    mask is [S * B, L] and each seed's valid rows are padded to one capacity, N = S * C with C
    the most valid tokens of any seed rounded up to `bucket` rows (padding rows repeat a
    token of their seed and are never spread back), so every seed's token-wise layers run on
    [C, W] in one batched product and shapes repeat across calls. `bucket` None (seeds = 1)
    keeps exactly the valid rows, as the exported graph does.
    """

    def __init__(self, mask: torch.Tensor, seeds: int = 1, bucket: int | None = None) -> None:
        if bucket is None:
            flat = mask.reshape(-1)
            (self.rows,) = torch.nonzero(flat, as_tuple=True)
            # Row k + 1 of [zeros; valid rows] is valid token k; padding reads row 0, the zeros.
            counted = flat.to(torch.int64).cumsum(0)
            self.slots = torch.where(flat, counted, torch.zeros_like(counted))
            return
        by_seed = mask.reshape(seeds, -1)  # [S, B * L]
        length = by_seed.shape[1]
        counted = by_seed.to(torch.int64).cumsum(1)
        capacity = capacity_of(counted[:, -1], bucket, length)
        first_row = length * torch.arange(seeds, device=mask.device)[:, None]
        # Valid token k of a seed is where its running count first reaches k + 1.
        wanted = torch.arange(1, capacity + 1, device=mask.device).expand(seeds, -1).contiguous()
        self.rows = (torch.searchsorted(counted, wanted).clamp_(max=length - 1) + first_row).reshape(-1)
        first_slot = capacity * torch.arange(seeds, device=mask.device)[:, None]
        self.slots = torch.where(by_seed, counted + first_slot, torch.zeros_like(counted)).reshape(-1)

    def gather(self, rows: torch.Tensor) -> torch.Tensor:
        """[B * L, W] -> the valid tokens' rows [N, W]."""
        return rows.index_select(0, self.rows)

    def spread(self, rows: torch.Tensor) -> torch.Tensor:
        """The valid tokens' rows [N, W] -> [B * L, W], zeros at padding."""
        with_zeros = torch.cat([rows.new_zeros(1, rows.shape[1]), rows])
        return with_zeros.index_select(0, self.slots)


def capacity_of(valid_counts: torch.Tensor, bucket: int, length: int) -> int:
    """Rows each seed's valid tokens are padded to: the most valid tokens of any seed (counts [S])
    rounded up to a multiple of `bucket`, at most `length` (B * L). On a GPU, where reading the
    counts would wait for the device, every seed keeps all `length` rows instead."""
    if valid_counts.device.type != "cpu":
        return length
    most = int(valid_counts.max())
    return min(-(-most // bucket) * bucket, length)


def attend(query: torch.Tensor, key: torch.Tensor, value: torch.Tensor, bias: torch.Tensor, heads: int,
           scale: float, weight_dropout: nn.Module | None = None) -> torch.Tensor:
    """Multi-head scaled dot-product attention: query, key, value [B, L, H] (heads packed
    along H), bias [B, 1, L, L] (`attention_bias`) -> [B, L, H]; softmax(q k^T * scale + bias) v,
    with `weight_dropout` (training only) applied to the attention weights."""
    query, key, value = (part.unflatten(-1, (heads, -1)).transpose(1, 2) for part in (query, key, value))
    weights = torch.softmax(torch.matmul(query, key.transpose(-2, -1)) * scale + bias, dim=-1)
    if weight_dropout is not None:
        weights = weight_dropout(weights)
    return torch.matmul(weights, value).transpose(1, 2).flatten(2)


class OnnxAttention(torch.autograd.Function):
    """`attend` in torch, one ONNX `Attention` op (opset 23) in an exported graph: one kernel
    in place of the head split, two batched products, scale, bias, softmax and head merge."""

    @staticmethod
    def forward(ctx, query, key, value, bias, heads: int, scale: float):  # noqa: D102
        return attend(query, key, value, bias, heads, scale)

    @staticmethod
    def symbolic(graph, query, key, value, bias, heads: int, scale: float):  # noqa: D102
        output = graph.op("Attention", query, key, value, bias, q_num_heads_i=heads, kv_num_heads_i=heads,
                          scale_f=scale)
        output.setType(query.type())
        return output


class MaskedSelfAttention(nn.Module):
    """Multi-head scaled dot-product self-attention; padded tokens are never attended to.

    Same parameters as nn.MultiheadAttention: a packed input projection
    Linear(H -> 3H) (query, key, value) and an output projection Linear(H -> H).
    Exported to ONNX as one `Attention` op between the two projections (`OnnxAttention`).
    """

    def __init__(self, hidden: int, heads: int, dropout: float = DROPOUT) -> None:
        super().__init__()
        if hidden % heads != 0:
            raise ValueError(f"hidden size {hidden} must be a multiple of the head count {heads}")
        self.heads = heads
        self.hidden = hidden
        self.in_proj = nn.Linear(hidden, 3 * hidden)
        self.out_proj = nn.Linear(hidden, hidden)
        self.dropout = nn.Dropout(dropout)
        self.scale = 1.0 / math.sqrt(hidden // heads)

    def forward(self, tokens: torch.Tensor, bias: torch.Tensor, valid: ValidTokens) -> torch.Tensor:
        """tokens [N, H] (the valid tokens of B sequences of L tokens, `valid`), bias
        [B, 1, L, L] (`attention_bias` of the mask) -> [N, H].

        The projections run on the valid rows; the attention on [B, L], where padded keys
        weigh exactly 0 whatever their (zero) projections.
        """
        # Split by constant sizes, not chunk: the exported parts keep a static width H.
        projected = valid.spread(self.in_proj(tokens)).reshape(bias.shape[0], -1, 3 * self.hidden)
        query, key, value = projected.split([self.hidden] * 3, dim=-1)
        if torch.onnx.is_in_onnx_export():
            attended = OnnxAttention.apply(query, key, value, bias, self.heads, self.scale)
        else:
            attended = attend(query, key, value, bias, self.heads, self.scale, self.dropout)
        # reshape to a constant width, not flatten: exported, its width H stays known.
        return self.out_proj(valid.gather(attended.reshape(-1, self.hidden)))


class TransformerLayer(nn.Module):
    """Pre-LayerNorm encoder layer: x + Attn(LN(x)), then x + FF(LN(x)), FF = H -> 4H -> H, ReLU."""

    def __init__(self, hidden: int, heads: int, dropout: float = DROPOUT) -> None:
        super().__init__()
        self.attention_norm = nn.LayerNorm(hidden)
        self.attention = MaskedSelfAttention(hidden, heads, dropout)
        self.attention_dropout = nn.Dropout(dropout)
        self.feedforward_norm = nn.LayerNorm(hidden)
        self.feedforward = nn.Sequential(
            nn.Linear(hidden, 4 * hidden),
            nn.ReLU(),
            nn.Dropout(dropout),
            nn.Linear(4 * hidden, hidden),
        )
        self.feedforward_dropout = nn.Dropout(dropout)

    def forward(self, tokens: torch.Tensor, bias: torch.Tensor, valid: ValidTokens) -> torch.Tensor:
        """tokens [N, H] (the valid tokens, `valid`), bias [B, 1, L, L] (`attention_bias` of
        the mask) -> [N, H]."""
        tokens = tokens + self.attention_dropout(
            self.attention(self.attention_norm(tokens), bias, valid)
        )
        return tokens + self.feedforward_dropout(self.feedforward(self.feedforward_norm(tokens)))


class TypeEmbedding(nn.Embedding):
    """The learned type embedding: one row [H] per entity type (ego 0, teammate 1, evader 2, obstacle 3)."""

    def __init__(self, hidden: int) -> None:
        super().__init__(NUM_ENTITY_TYPES, hidden)

    def add(self, tokens: torch.Tensor, kind: int) -> torch.Tensor:
        """tokens [..., H] of entity type `kind` plus that type's row."""
        # Adding by broadcasting needs no per-token type ids, whose length would depend on P, E and O.
        return tokens + self.weight[kind]


class RelationExtractor(nn.Module):
    """Per-type encoders, learned type embedding and L transformer layers (paper IV-B 1-2)."""

    def __init__(self, hidden: int, layers: int, heads: int) -> None:
        super().__init__()
        self.encoders = EntityEncoders(hidden)
        self.type_embedding = TypeEmbedding(hidden)
        self.layers = nn.ModuleList(TransformerLayer(hidden, heads) for _ in range(layers))
        self.seeds = 1
        """networks whose rows a call holds, seed-major (training.networks.stacked sets it)."""
        self.token_bucket: int | None = None
        """None: the token-wise layers see exactly the valid tokens; K: each seed's, padded to a
        multiple of K rows (`ValidTokens`)."""

    def forward(
        self,
        ego: torch.Tensor,
        teammates: torch.Tensor,
        evaders: torch.Tensor,
        obstacles: torch.Tensor,
        mask: torch.Tensor,
    ) -> torch.Tensor:
        """[B, 4], [B, P, 7], [B, E, 7], [B, O, 5], mask [B, L] -> token outputs [B, L, H],
        zeros at padding.

        Token order is the mask order: ego, teammates, evaders, obstacles.
        """
        groups = self.encoders(ego, teammates, evaders, obstacles)
        types = self.type_embedding
        tokens = torch.cat(
            [
                types.add(groups.ego, 0).unsqueeze(1),
                types.add(groups.teammates, 1),
                types.add(groups.evaders, 2),
                types.add(groups.obstacles, 3),
            ],
            dim=1,
        )
        bias = attention_bias(mask)
        valid = ValidTokens(mask, self.seeds, self.token_bucket)
        # Token-wise layers see the valid rows [N, H]: 2-D products export as Gemm, bias inside.
        rows = valid.gather(tokens.flatten(0, 1))
        for layer in self.layers:
            rows = layer(rows, bias, valid)
        return valid.spread(rows).reshape(tokens.shape)


def ego_and_global(tokens: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """[s, g]: the ego token output and the masked max-pool of all outputs, [B, L, H] -> [B, 2H].

    The published code max-pools over padding too; here padding is masked out, so
    the context does not depend on how many empty slots a scenario has.
    """
    return torch.cat([tokens[:, 0], masked_max(tokens, mask)], dim=-1)


class TERLNetwork(QNetwork):
    """TERL: relation extraction, target selection over evader token outputs, IQN head.

    Published size H = 256, h = 8, L = 4: 3,583,497 parameters (the paper's
    3.58 M). The count has no final LayerNorm after the last pre-LN layer, as in
    the published code (nn.TransformerEncoder without `norm`).
    """

    model_name = "terl"
    has_target_selection = True

    def __init__(self, hidden: int = 256, layers: int = 4, heads: int = 8) -> None:
        super().__init__(hidden, layers, heads)
        self.relations = RelationExtractor(hidden, layers, heads)
        self.context = nn.Linear(2 * hidden, hidden)
        self.target_selection = TargetSelection(hidden)
        self.head = self.make_head()

    def embed(
        self,
        ego: torch.Tensor,
        teammates: torch.Tensor,
        evaders: torch.Tensor,
        obstacles: torch.Tensor,
        mask: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Observation (see `QNetwork.forward`) -> z [B, H], target weights [B, E]."""
        tokens = self.relations(ego, teammates, evaders, obstacles, mask)
        context = self.context(ego_and_global(tokens, mask))
        num_teammates, num_evaders = teammates.shape[1], evaders.shape[1]
        evader_tokens = tokens[:, 1 + num_teammates : 1 + num_teammates + num_evaders]
        evader_mask = split_mask(mask, num_teammates, num_evaders).evaders
        return self.target_selection(context, evader_tokens, evader_mask)


class TERLNoTargetSelection(QNetwork):
    """Ablation `terl-no-ts`: the TERL transformer, Linear(2H -> H)([s, g]) straight into the IQN head."""

    model_name = "terl-no-ts"

    def __init__(self, hidden: int = 256, layers: int = 4, heads: int = 8) -> None:
        super().__init__(hidden, layers, heads)
        self.relations = RelationExtractor(hidden, layers, heads)
        self.context = nn.Linear(2 * hidden, hidden)
        self.head = self.make_head()

    def embed(
        self,
        ego: torch.Tensor,
        teammates: torch.Tensor,
        evaders: torch.Tensor,
        obstacles: torch.Tensor,
        mask: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Observation (see `QNetwork.forward`) -> z [B, H], None."""
        tokens = self.relations(ego, teammates, evaders, obstacles, mask)
        return self.context(ego_and_global(tokens, mask)), None
