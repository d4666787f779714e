"""The network models a policy may be (the `terl.model` metadata, policy.md section 1), in
the paper's order: one registry, read by the paper's report, training's config and its cards.

This file imports nothing of the runtime, nor torch: training validates a config's model
against it before any network is built, and `training.networks` maps each name to its class.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Model:
    """One network model: how the metadata names it, how the paper does, and its body."""

    name: str
    """the `terl.model` metadata and the recipe stem, e.g. "terl-no-re"."""
    label: str
    """the paper's name of the method in its tables, e.g. "w/o RE"."""
    title: str
    """the paper's name spelt out, as a model card gives it."""
    transformer: bool
    """True when the body has transformer layers (L, h >= 1); a body without records both as 0."""


MODELS: dict[str, Model] = {
    model.name: model
    for model in (
        Model("terl", "TERL", "TERL", transformer=True),
        Model("iqn", "IQN", "IQN", transformer=False),
        Model("dqn", "DQN", "DQN", transformer=False),
        Model("mean", "MEAN", "MEAN", transformer=False),
        Model("terl-no-re", "w/o RE", "TERL w/o RE (relation extraction)", transformer=False),
        Model("terl-no-ts", "w/o TS", "TERL w/o TS (target selection)", transformer=True),
    )
}
"""model name -> model, in the paper's order (TERL, its baselines, its ablations)."""


def model_title(name: str) -> str:
    """The paper's name of a model, spelt out; a model it does not have keeps its own name."""
    return MODELS[name].title if name in MODELS else name
