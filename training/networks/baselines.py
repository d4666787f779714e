"""Baselines and the `terl-no-re` ablation (policy.md section 1, paper section V).

None of these bodies has a transformer (`QNetwork.has_transformer` false): the
constructors accept `layers` and `heads` so every model is built the same way, and
`QNetwork` records both as 0, the value the contract metadata gives for bodies
without them.
"""

from __future__ import annotations

import torch
from torch import nn

from training.networks.encoders import (
    EntityEncoders,
    QHead,
    QNetwork,
    TargetSelection,
    TokenGroups,
    masked_mean,
    split_mask,
)


def mlp(widths: list[int]) -> nn.Sequential:
    """Linear layers between consecutive widths, each followed by ReLU: [..., widths[0]] -> [..., widths[-1]]."""
    layers: list[nn.Module] = []
    for width_in, width_out in zip(widths[:-1], widths[1:]):
        layers += [nn.Linear(width_in, width_out), nn.ReLU()]
    return nn.Sequential(*layers)


def type_means(groups: TokenGroups, mask: torch.Tensor) -> TokenGroups:
    """Masked mean of each entity type's encoded tokens: [B, H] each (ego is its one token)."""
    masks = split_mask(mask, groups.teammates.shape[1], groups.evaders.shape[1])
    return TokenGroups(
        groups.ego,
        masked_mean(groups.teammates, masks.teammates),
        masked_mean(groups.evaders, masks.evaders),
        masked_mean(groups.obstacles, masks.obstacles),
    )


class IQNBaseline(QNetwork):
    """`iqn`: per-type encoders, masked mean per type, concat (4H), MLP 4H -> 2H -> 2H -> 2H -> H, IQN head."""

    model_name = "iqn"

    def __init__(self, hidden: int = 256, layers: int = 0, heads: int = 0) -> None:
        super().__init__(hidden, layers, heads)
        self.encoders = EntityEncoders(hidden)
        self.body = mlp([4 * hidden, 2 * hidden, 2 * hidden, 2 * hidden, hidden])
        self.head = self.make_head()

    def encode(
        self,
        ego: torch.Tensor,
        teammates: torch.Tensor,
        evaders: torch.Tensor,
        obstacles: torch.Tensor,
        mask: torch.Tensor,
    ) -> tuple[torch.Tensor, TokenGroups]:
        """Observation -> body output [B, H] and the encoded token groups."""
        groups = self.encoders(ego, teammates, evaders, obstacles)
        return self.body(torch.cat(type_means(groups, mask), dim=-1)), groups

    def embed(
        self,
        ego: torch.Tensor,
        teammates: torch.Tensor,
        evaders: torch.Tensor,
        obstacles: torch.Tensor,
        mask: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Observation (see `QNetwork.forward`) -> z [B, H], None."""
        return self.encode(ego, teammates, evaders, obstacles, mask)[0], None


class DQNBaseline(IQNBaseline):
    """`dqn`: the `iqn` body with a plain Q head; forward returns Q-values [B, 1, 9] and ignores taus."""

    model_name = "dqn"
    distributional = False

    def make_head(self) -> nn.Module:
        """Linear(H -> 9)."""
        return QHead(self.hidden_size, self.num_actions)


class MeanBaseline(QNetwork):
    """`mean`: per-type masked means, their mean (H), MLP H -> 2H -> 2H -> 2H -> H, IQN head."""

    model_name = "mean"

    def __init__(self, hidden: int = 256, layers: int = 0, heads: int = 0) -> None:
        super().__init__(hidden, layers, heads)
        self.encoders = EntityEncoders(hidden)
        self.body = mlp([hidden, 2 * hidden, 2 * hidden, 2 * hidden, hidden])
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
        groups = self.encoders(ego, teammates, evaders, obstacles)
        # A type with no valid slot contributes a zero mean and still counts as one of 4.
        pooled = torch.stack(type_means(groups, mask), dim=1).mean(dim=1)
        return self.body(pooled), None


class TERLNoRelationExtraction(IQNBaseline):
    """Ablation `terl-no-re`: the `iqn` body as context c, target selection over evader encoder outputs."""

    model_name = "terl-no-re"
    has_target_selection = True

    def __init__(self, hidden: int = 256, layers: int = 0, heads: int = 0) -> None:
        super().__init__(hidden, layers, heads)
        self.target_selection = TargetSelection(hidden)

    def embed(
        self,
        ego: torch.Tensor,
        teammates: torch.Tensor,
        evaders: torch.Tensor,
        obstacles: torch.Tensor,
        mask: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Observation (see `QNetwork.forward`) -> z [B, H], target weights [B, E]."""
        context, groups = self.encode(ego, teammates, evaders, obstacles, mask)
        evader_mask = split_mask(mask, teammates.shape[1], evaders.shape[1]).evaders
        return self.target_selection(context, groups.evaders, evader_mask)
