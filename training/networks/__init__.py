"""Pursuer Q-networks: TERL, its ablations and the baselines, behind one registry.

Every network is a `QNetwork` with the same call:
`model(ego, teammates, evaders, obstacles, mask, taus) -> NetworkOutput(quantiles, target_weights)`
and `model.q_values(ego, teammates, evaders, obstacles, mask) -> [B, 9]`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from torch import nn

from training.networks.baselines import (
    DQNBaseline,
    IQNBaseline,
    MeanBaseline,
    TERLNoRelationExtraction,
)
from training.networks.encoders import NetworkOutput, QNetwork, fixed_fractions
from training.networks.terl import TERLNetwork, TERLNoTargetSelection

if TYPE_CHECKING:
    from training.config import NetworkConfig

__all__ = [
    "DQNBaseline",
    "IQNBaseline",
    "MeanBaseline",
    "NetworkOutput",
    "QNetwork",
    "TERLNetwork",
    "TERLNoRelationExtraction",
    "TERLNoTargetSelection",
    "build_network",
    "fixed_fractions",
    "network_classes",
    "network_from_config",
]


def network_classes() -> dict[str, type[QNetwork]]:
    """Model name (terl_rt.policy.models) -> class, for `terl`, `iqn`, `dqn`, `mean`, `terl-no-re`,
    `terl-no-ts`."""
    classes = (
        TERLNetwork,
        IQNBaseline,
        DQNBaseline,
        MeanBaseline,
        TERLNoRelationExtraction,
        TERLNoTargetSelection,
    )
    return {cls.model_name: cls for cls in classes}


def build_network(name: str, hidden: int = 256, layers: int = 4, heads: int = 8) -> QNetwork:
    """Build a network by registry name; `build_network(**model.config)` rebuilds `model`.

    Args:
        name: one of `network_classes()`.
        hidden: token and feature width H.
        layers: transformer layers L (recorded as 0 by bodies without a transformer).
        heads: attention heads h, must divide H (recorded as 0 by bodies without a transformer).
    """
    classes = network_classes()
    if name not in classes:
        raise ValueError(f"unknown network '{name}'; expected one of {sorted(classes)}")
    return classes[name](hidden=hidden, layers=layers, heads=heads)


def network_from_config(network: NetworkConfig) -> QNetwork:
    """The network a config's network part describes (fresh weights), its dropout layers at `network.dropout`."""
    model = build_network(network.model, network.hidden, network.layers, network.heads)
    for module in model.modules():
        if isinstance(module, nn.Dropout):
            module.p = network.dropout
    return model
