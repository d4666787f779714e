"""Pieces every Q-network shares (policy.md section 1): the per-entity-type
encoders, masked pooling, the masked softmax, target selection, the IQN head and
the `QNetwork` base class that fixes one call signature for all models.

Shape letters: B batch rows (one pursuer's observation each), P teammate slots,
E evader slots, O obstacle slots, L = 1 + P + E + O tokens, H hidden width,
K quantile fractions, A = 9 pursuer actions.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, NamedTuple

import torch
from torch import nn

from terl_rt.policy.contract import EGO_FEATURES, EVADER_FEATURES, OBSTACLE_FEATURES, TEAMMATE_FEATURES
from terl_rt.policy.models import MODELS
from terl_rt.sim.actions import PURSUER_ACTIONS

NUM_COSINES = 64
"""Cosine features of the IQN fraction embedding, cos(pi * i * tau) for i = 0..63."""
NUM_FIXED_FRACTIONS = 32
"""K of the deterministic Q-values: fractions tau_k = (k + 0.5) / K."""


class NetworkOutput(NamedTuple):
    """What every network's forward returns."""

    quantiles: torch.Tensor
    """[B, K, A] return quantiles at the given fractions; [B, 1, A] Q-values for `dqn`."""
    target_weights: torch.Tensor | None
    """[B, E] target preference, sums to 1 over valid evader slots and is 0 on padding
    (all 0 when a row has no valid evader); None for models without target selection."""


class TokenGroups(NamedTuple):
    """One tensor per entity type, in mask order."""

    ego: torch.Tensor
    teammates: torch.Tensor
    evaders: torch.Tensor
    obstacles: torch.Tensor


def entity_encoder(in_features: int, hidden: int) -> nn.Sequential:
    """Linear(in_features -> hidden) -> LayerNorm(hidden) -> ReLU, applied per token."""
    return nn.Sequential(nn.Linear(in_features, hidden), nn.LayerNorm(hidden), nn.ReLU())


class EntityEncoders(nn.Module):
    """One `entity_encoder` per entity type (ego 4, teammate 7, evader 7, obstacle 5 features)."""

    def __init__(self, hidden: int) -> None:
        super().__init__()
        self.ego = entity_encoder(EGO_FEATURES, hidden)
        self.teammate = entity_encoder(TEAMMATE_FEATURES, hidden)
        self.evader = entity_encoder(EVADER_FEATURES, hidden)
        self.obstacle = entity_encoder(OBSTACLE_FEATURES, hidden)

    def forward(
        self,
        ego: torch.Tensor,
        teammates: torch.Tensor,
        evaders: torch.Tensor,
        obstacles: torch.Tensor,
    ) -> TokenGroups:
        """[B, 4], [B, P, 7], [B, E, 7], [B, O, 5] in; [B, H], [B, P, H], [B, E, H], [B, O, H] out."""
        return TokenGroups(
            self.ego(ego), self.teammate(teammates), self.evader(evaders), self.obstacle(obstacles)
        )


def split_mask(mask: torch.Tensor, num_teammates: int, num_evaders: int) -> TokenGroups:
    """Mask [B, 1 + P + E + O] -> ego [B], teammates [B, P], evaders [B, E], obstacles [B, O]."""
    evaders_start = 1 + num_teammates
    obstacles_start = evaders_start + num_evaders
    return TokenGroups(
        mask[:, 0],
        mask[:, 1:evaders_start],
        mask[:, evaders_start:obstacles_start],
        mask[:, obstacles_start:],
    )


def zero_padding(features: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Features [B, S, F] with padded slots (mask [B, S] false) set to 0, even if NaN."""
    return torch.where(mask.unsqueeze(-1), features, torch.zeros_like(features))


def masked_mean(tokens: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean over valid tokens: [B, S, H], mask [B, S] -> [B, H]; 0 where a row has none."""
    valid = mask.unsqueeze(-1)
    total = torch.where(valid, tokens, torch.zeros_like(tokens)).sum(dim=1)
    count = valid.sum(dim=1).clamp(min=1).to(tokens.dtype)
    return total / count


def masked_max(tokens: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Element-wise max over valid tokens: [B, S, H], mask [B, S] -> [B, H]; 0 where a row has none."""
    valid = mask.unsqueeze(-1)
    lowest = torch.full_like(tokens, torch.finfo(tokens.dtype).min)
    pooled = torch.where(valid, tokens, lowest).amax(dim=1)
    return torch.where(valid.any(dim=1), pooled, torch.zeros_like(pooled))


def masked_softmax(scores: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Softmax over the last axis restricted to mask-true entries.

    scores [..., S], mask broadcastable to it -> weights [..., S] that sum to 1 over
    the valid entries, are exactly 0 on invalid ones, and are all 0 (not NaN) where
    no entry is valid.
    """
    # The finite fill keeps an all-invalid row finite (uniform); the final product zeroes it.
    lowest = torch.finfo(scores.dtype).min
    filled = scores.masked_fill(~mask, lowest)
    return torch.softmax(filled, dim=-1) * mask.to(scores.dtype)


class TargetSelection(nn.Module):
    """Single-query scaled dot-product attention of a context over evader tokens (paper IV-B).

    query = Linear(H -> H)(c); keys and values = Linear(H -> H) of the evader tokens;
    w = softmax(q . k / sqrt(H)) over valid slots; z = LayerNorm(c + w . V).
    """

    def __init__(self, hidden: int) -> None:
        super().__init__()
        self.query = nn.Linear(hidden, hidden)
        self.key = nn.Linear(hidden, hidden)
        self.value = nn.Linear(hidden, hidden)
        self.norm = nn.LayerNorm(hidden)
        self.scale = 1.0 / math.sqrt(hidden)

    def forward(
        self, context: torch.Tensor, evader_tokens: torch.Tensor, evader_mask: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """context c [B, H], evader_tokens [B, E, H], evader_mask [B, E] bool -> z [B, H], w [B, E]."""
        query = self.query(context).unsqueeze(1)
        scores = (query * self.key(evader_tokens)).sum(dim=-1) * self.scale
        weights = masked_softmax(scores, evader_mask)
        attended = torch.bmm(weights.unsqueeze(1), self.value(evader_tokens)).squeeze(1)
        return self.norm(context + attended), weights


def float32_output(layer: nn.Linear, features: torch.Tensor) -> torch.Tensor:
    """`layer` of `features` in float32 even under autocast (LearnerConfig.bf16): the values a loss
    compares keep float32's precision, whatever precision the body ran in."""
    with torch.autocast(features.device.type, enabled=False):
        return layer(features.float())


class IQNHead(nn.Module):
    """Implicit quantile head (Dabney et al. 2018, as in paper IV-B).

    phi(tau) = ReLU(Linear(64 -> H)([cos(pi i tau)], i = 0..63)),
    u = LayerNorm(ReLU(Linear(H -> H)(z * phi(tau)))), quantiles = Linear(H -> A)(u).
    """

    def __init__(self, hidden: int, num_actions: int, num_cosines: int = NUM_COSINES) -> None:
        super().__init__()
        self.cosine = nn.Linear(num_cosines, hidden)
        self.hidden = nn.Linear(hidden, hidden)
        self.norm = nn.LayerNorm(hidden)
        self.out = nn.Linear(hidden, num_actions)
        # Not persistent: a constant, rebuilt from num_cosines, kept out of checkpoints.
        frequencies = math.pi * torch.arange(num_cosines, dtype=torch.float32)
        self.register_buffer("frequencies", frequencies, persistent=False)

    def forward(self, features: torch.Tensor, taus: torch.Tensor | None) -> torch.Tensor:
        """features z [B, H], taus [B, K] (or [1, K], shared by all rows) in [0, 1] -> [B, K, A]."""
        if taus is None:
            raise ValueError("an IQN head needs quantile fractions taus [B, K]; got None")
        cosines = torch.cos(taus.unsqueeze(-1) * self.frequencies)
        embedding = torch.relu(self.cosine(cosines))
        mixed = features.unsqueeze(1) * embedding
        return float32_output(self.out, self.norm(torch.relu(self.hidden(mixed))))


class QHead(nn.Module):
    """Plain Q head Linear(H -> A) for `dqn`; returns its Q-values as one "quantile"."""

    def __init__(self, hidden: int, num_actions: int) -> None:
        super().__init__()
        self.out = nn.Linear(hidden, num_actions)

    def forward(self, features: torch.Tensor, taus: torch.Tensor | None = None) -> torch.Tensor:
        """features [B, H], taus ignored -> Q-values [B, 1, A]."""
        return float32_output(self.out, features).unsqueeze(1)


def fixed_fractions(
    num: int = NUM_FIXED_FRACTIONS, device: torch.device | None = None
) -> torch.Tensor:
    """Deterministic quantile fractions tau_k = (k + 0.5) / num, k = 0..num-1: [1, num]."""
    k = torch.arange(num, dtype=torch.float32, device=device)
    return ((k + 0.5) / num).unsqueeze(0)


def check_inputs(
    ego: torch.Tensor,
    teammates: torch.Tensor,
    evaders: torch.Tensor,
    obstacles: torch.Tensor,
    mask: torch.Tensor,
) -> None:
    """Raise ValueError naming expected against received shapes when the inputs break the layout."""
    expected = {
        "ego": (ego, 2, EGO_FEATURES),
        "teammates": (teammates, 3, TEAMMATE_FEATURES),
        "evaders": (evaders, 3, EVADER_FEATURES),
        "obstacles": (obstacles, 3, OBSTACLE_FEATURES),
    }
    batch = ego.shape[0]
    for name, (tensor, rank, features) in expected.items():
        if tensor.dim() != rank or tensor.shape[-1] != features or tensor.shape[0] != batch:
            raise ValueError(
                f"{name}: expected [B={batch}{', S' if rank == 3 else ''}, {features}], "
                f"got {list(tensor.shape)}"
            )
    width = 1 + teammates.shape[1] + evaders.shape[1] + obstacles.shape[1]
    if mask.dtype != torch.bool or tuple(mask.shape) != (batch, width):
        raise ValueError(
            f"mask: expected bool [B={batch}, 1+P+E+O={width}], "
            f"got {mask.dtype} {list(mask.shape)}"
        )


class QNetwork(nn.Module):
    """Base of every pursuer Q-network: one call signature, one head interface.

    Subclasses set `model_name` (a name of terl_rt.policy.models, which says whether the body
    has a transformer), `has_target_selection` and `distributional`, build their body in `__init__` and implement `embed`. `config` holds the construction
    arguments, so `build_network(**model.config)` rebuilds the same architecture.

    The head is an `IQNHead` (quantiles at the given fractions) except for `dqn`,
    whose `QHead` ignores `taus` and returns its Q-values as a single "quantile"
    [B, 1, A]; `q_values` is then the same mean over axis 1 for every model.
    """

    model_name: ClassVar[str] = ""
    """Registry name, written to the ONNX metadata as `terl.model`."""
    has_transformer: ClassVar[bool] = False
    """True when the body has transformer layers (L, h >= 1); a body without records both as 0,
    the value the contract metadata gives. Set from the registry's `Model.transformer`."""
    has_target_selection: ClassVar[bool] = False
    """True when forward returns target_weights [B, E]."""
    distributional: ClassVar[bool] = True
    """True for IQN heads (quantile Huber loss), False for `dqn` (Huber TD loss)."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        cls.has_transformer = MODELS[cls.model_name].transformer

    def __init__(self, hidden: int, layers: int, heads: int) -> None:
        super().__init__()
        self.hidden_size = hidden
        self.num_layers = layers if self.has_transformer else 0
        self.num_heads = heads if self.has_transformer else 0
        self.num_actions = len(PURSUER_ACTIONS)

    @property
    def config(self) -> dict[str, Any]:
        """Construction arguments: name, hidden, layers, heads."""
        return {
            "name": self.model_name,
            "hidden": self.hidden_size,
            "layers": self.num_layers,
            "heads": self.num_heads,
        }

    def make_head(self) -> nn.Module:
        """The action-value head: `IQNHead(H -> A)` unless a subclass says otherwise."""
        return IQNHead(self.hidden_size, self.num_actions)

    def embed(
        self,
        ego: torch.Tensor,
        teammates: torch.Tensor,
        evaders: torch.Tensor,
        obstacles: torch.Tensor,
        mask: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Body: observation -> features z [B, H] and target weights [B, E] (or None)."""
        raise NotImplementedError

    def forward(
        self,
        ego: torch.Tensor,
        teammates: torch.Tensor,
        evaders: torch.Tensor,
        obstacles: torch.Tensor,
        mask: torch.Tensor,
        taus: torch.Tensor | None = None,
    ) -> NetworkOutput:
        """Quantiles of every pursuer action's return at the fractions `taus`.

        Args:
            ego: [B, 4] float32, [vx, vy (m/s), d_nearest (m), pursuit_status].
            teammates: [B, P, 7] float32, world.md section 5 features.
            evaders: [B, E, 7] float32.
            obstacles: [B, O, 5] float32.
            mask: [B, 1 + P + E + O] bool, true = slot present (ego always true).
            taus: [B, K] (or [1, K]) quantile fractions in [0, 1]; ignored by `dqn`.

        Returns:
            NetworkOutput: quantiles [B, K, 9] ([B, 1, 9] Q-values for `dqn`) and
            target_weights [B, E] or None. Values in padded slots never matter.
        """
        if not torch.jit.is_tracing():
            check_inputs(ego, teammates, evaders, obstacles, mask)
        masks = split_mask(mask, teammates.shape[1], evaders.shape[1])
        features, weights = self.embed(
            ego,
            zero_padding(teammates, masks.teammates),
            zero_padding(evaders, masks.evaders),
            zero_padding(obstacles, masks.obstacles),
            mask,
        )
        return NetworkOutput(self.head(features, taus), weights)

    def policy_outputs(
        self,
        ego: torch.Tensor,
        teammates: torch.Tensor,
        evaders: torch.Tensor,
        obstacles: torch.Tensor,
        mask: torch.Tensor,
        taus: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The contract outputs from one pass: q_values [B, 9] and target_weights [B, E] or None.

        Q-values are the mean of the quantiles at `taus` [B, K]; the contract's are the fixed
        fractions (k + 0.5) / 32 (taus None), so they are deterministic given the weights (in
        eval mode).
        """
        if taus is None:
            taus = fixed_fractions(device=ego.device)
        output = self(ego, teammates, evaders, obstacles, mask, taus)
        return output.quantiles.mean(dim=1), output.target_weights

    def q_values(
        self,
        ego: torch.Tensor,
        teammates: torch.Tensor,
        evaders: torch.Tensor,
        obstacles: torch.Tensor,
        mask: torch.Tensor,
        taus: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Expected return of each pursuer action, [B, 9]; inputs as in `policy_outputs`."""
        return self.policy_outputs(ego, teammates, evaders, obstacles, mask, taus)[0]
