"""The TERL network (policy.md section 1, paper section IV-B) and its `terl-no-ts` ablation.

Observation embedding -> relation extraction (type embedding + pre-LayerNorm
transformer encoder) -> target selection -> IQN head. Attention is written out
here rather than taken from nn.MultiheadAttention: it exports to ONNX as plain
MatMul/Softmax, and it has no fast path or nested-tensor branch that changes what
is computed for partly padded rows.
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
    masked_softmax,
    split_mask,
)

DROPOUT = 0.1
"""Dropout probability inside the transformer layers, in training mode only."""
NUM_ENTITY_TYPES = 4
"""Rows of the type embedding: ego 0, teammate 1, evader 2, obstacle 3."""


class MaskedSelfAttention(nn.Module):
    """Multi-head scaled dot-product self-attention; padded tokens are never attended to.

    Same parameters as nn.MultiheadAttention: a packed input projection
    Linear(H -> 3H) (query, key, value) and an output projection Linear(H -> H).
    """

    def __init__(self, hidden: int, heads: int, dropout: float = DROPOUT) -> None:
        super().__init__()
        if hidden % heads != 0:
            raise ValueError(f"hidden size {hidden} must be a multiple of the head count {heads}")
        self.heads = heads
        self.in_proj = nn.Linear(hidden, 3 * hidden)
        self.out_proj = nn.Linear(hidden, hidden)
        self.dropout = nn.Dropout(dropout)
        self.scale = 1.0 / math.sqrt(hidden // heads)

    def forward(self, tokens: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """tokens [B, L, H], mask [B, L] bool (true = valid key) -> [B, L, H].

        Padded query positions still get (finite) outputs; callers ignore them.
        """
        query, key, value = (
            part.unflatten(-1, (self.heads, -1)).transpose(1, 2)
            for part in self.in_proj(tokens).chunk(3, dim=-1)
        )
        scores = torch.matmul(query, key.transpose(-2, -1)) * self.scale
        weights = self.dropout(masked_softmax(scores, mask[:, None, None, :]))
        attended = torch.matmul(weights, value).transpose(1, 2).flatten(2)
        return self.out_proj(attended)


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

    def forward(self, tokens: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """tokens [B, L, H], mask [B, L] bool -> [B, L, H]."""
        tokens = tokens + self.attention_dropout(
            self.attention(self.attention_norm(tokens), mask)
        )
        return tokens + self.feedforward_dropout(self.feedforward(self.feedforward_norm(tokens)))


class RelationExtractor(nn.Module):
    """Per-type encoders, learned type embedding and L transformer layers (paper IV-B 1-2)."""

    def __init__(self, hidden: int, layers: int, heads: int) -> None:
        super().__init__()
        self.encoders = EntityEncoders(hidden)
        self.type_embedding = nn.Embedding(NUM_ENTITY_TYPES, hidden)
        self.layers = nn.ModuleList(TransformerLayer(hidden, heads) for _ in range(layers))

    def forward(
        self,
        ego: torch.Tensor,
        teammates: torch.Tensor,
        evaders: torch.Tensor,
        obstacles: torch.Tensor,
        mask: torch.Tensor,
    ) -> torch.Tensor:
        """[B, 4], [B, P, 7], [B, E, 7], [B, O, 5], mask [B, L] -> token outputs [B, L, H].

        Token order is the mask order: ego, teammates, evaders, obstacles.
        """
        groups = self.encoders(ego, teammates, evaders, obstacles)
        # Adding each group's type row by broadcasting needs no per-token type ids,
        # whose length would depend on P, E and O.
        types = self.type_embedding.weight
        tokens = torch.cat(
            [
                (groups.ego + types[0]).unsqueeze(1),
                groups.teammates + types[1],
                groups.evaders + types[2],
                groups.obstacles + types[3],
            ],
            dim=1,
        )
        for layer in self.layers:
            tokens = layer(tokens, mask)
        return tokens


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
