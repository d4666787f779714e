"""The learner of S seeds trained together: their online and target networks, Adam and the update.

Every seed is exactly itself: its own weights, target, Adam state, gradient-norm clip and
quantile fractions (drawn from a generator of its own), on its own sampled batch. What the
seeds share is the call: the weights of all S networks are rows of flat tensors [S, P]
(training.networks.stacked), so one forward and backward of the stacked network, one clip
and one fused Adam step serve every seed, for about the dispatch cost of one seed.

One seed is S = 1: the training loop has one learner, whatever the number of seeds.
`seed_state` and `load_seed_state` read and write a seed's part in the layout a one-seed run
checkpoints (a plain network's state dicts and a plain Adam's), so checkpoints, resume and
export see no difference.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import warnings

import numpy as np
import torch

from training.adam import RowAdam, one_seed_state_dict
from training.buffer import ReplayBatch, trim_padding
from training.config import LearnerConfig, NetworkConfig
from training.losses import huber, quantile_huber_rows, quantile_td_target, td_target
from training.networks import QNetwork, network_from_config
from training.networks.stacked import flat_view, flatten_weights, parameter_slices, seed_network, stack_network
from training.torch_policy import as_tensors

# Each stacked weight is a view of a row-strided flat tensor, and so is its gradient: autograd
# accumulates into it in place all the same, and says once that the layouts are not its own.
warnings.filterwarnings("ignore", message="grad and param do not obey the gradient layout contract")

CLIP_EPS = 1e-6
"""Added to the gradient norm before dividing, as torch.nn.utils.clip_grad_norm_ does."""


class Learner:
    """Online and target networks, Adam and the TD update of S seeds (`seeds`, in order).

    Seed k's networks are built as a one-seed run builds them: the torch generator seeded
    with its seed, then its online network drawn (the target a copy of it); the generator's
    state after that seeds its quantile fractions (`generators[k]`), as the one-seed run's
    global generator went on. Acting, snapshots and checkpoints use `online[k]` and `target[k]`,
    plain networks over row k of the flat weights.
    """

    def __init__(self, network: NetworkConfig, learner: LearnerConfig, seeds: Sequence[int]) -> None:
        if not seeds:
            raise ValueError("Learner: no seeds to train")
        self.config = learner
        self.device = torch.device(learner.device)
        networks, generators = [], []
        for seed in seeds:
            torch.manual_seed(seed)
            networks.append(network_from_config(network))
            generator = torch.Generator()
            generator.set_state(torch.get_rng_state())
            generators.append(generator)
        # Flattened before the template moves: Module.to moves networks[0] in place.
        weights = flatten_weights(networks).to(self.device)
        self.template = networks[0].to(self.device)
        self.seeds = list(seeds)
        self.generators = generators
        """[S] each seed's CPU generator of quantile fractions (saved in its checkpoints as "torch")."""
        self._build(weights, weights.clone(), [None] * len(seeds))

    def _build(self, online: torch.Tensor, target: torch.Tensor, adam_states: list[dict[str, Any] | None]) -> None:
        """Lay out the seeds' flat weights online and target [S, P], their stacked and per-seed
        networks, and Adam with each seed's state (None: fresh)."""
        self.weights, self.target_weights = online, target
        self.gradients = torch.zeros_like(online)
        self.network = stack_network(self.template, online, trainable=True)
        # Gradients accumulate in place into views of one flat tensor [S, P]: one clip for all.
        slices = parameter_slices(self.template)
        for name, parameter in self.network.named_parameters():
            parameter.grad = flat_view(self.gradients, *slices[name])
        self.target_network = stack_network(self.template, target, trainable=False).eval()
        self.online = [seed_network(self.template, online, k).eval() for k in range(len(self.seeds))]
        """[S] plain networks over each seed's online weights (eval mode): acting, snapshots, checkpoints."""
        self.target = [seed_network(self.template, target, k).eval() for k in range(len(self.seeds))]
        # With actor_update_frequency a copy of the online weights acts, refreshed by `refresh_actors`.
        self.acting_weights = online.clone() if self.config.actor_update_frequency else online
        self.actors = (
            [seed_network(self.template, self.acting_weights, k).eval() for k in range(len(self.seeds))]
            if self.config.actor_update_frequency else self.online
        )
        """[S] the networks that act in training: `online`, or copies of it (LearnerConfig.actor_update_frequency)."""
        # Adam over each seed's row of the flat weights, so each keeps its own step count.
        seeds = range(len(self.seeds))
        self.optimizer = RowAdam([online[k] for k in seeds], [self.gradients[k] for k in seeds],
                                 self.config.learning_rate, adam_states)

    @property
    def size(self) -> int:
        """S: the seeds trained."""
        return len(self.seeds)

    # --- the update
    def set_learning_rate(self, learning_rate: float) -> None:
        """Adam's step size for every seed (the schedule's, not the rate a resumed optimizer saved)."""
        self.optimizer.learning_rate = learning_rate

    def update(self, batches: Sequence[ReplayBatch], trim: bool = True) -> torch.Tensor:
        """One Adam step of every seed on its batch (`batches[k]` for seed k, R rows each), its
        gradient norm clipped to `max_grad_norm` alone; returns the losses [S] (on the device)."""
        self.network.train()
        self.gradients.zero_()
        losses = td_losses(self.network, self.target_network, concatenate(batches), self.config, self.generators, trim)
        losses.sum().backward()  # each seed's loss reaches its own weights alone
        norms = torch.linalg.vector_norm(self.gradients, dim=1)
        self.gradients.mul_((self.config.max_grad_norm / (norms + CLIP_EPS)).clamp_(max=1.0).unsqueeze(1))
        self.optimizer.step()
        return losses.detach()

    def copy_target(self) -> None:
        """The hard target copy of every seed."""
        self.target_weights.copy_(self.weights)

    def refresh_actors(self) -> None:
        """The acting copies take the online weights (nothing to do when the online networks act)."""
        if self.acting_weights is not self.weights:
            self.acting_weights.copy_(self.weights)

    # --- a seed's part, in a one-seed run's layout
    def seed_state(self, k: int) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor], dict[str, Any]]:
        """Seed k's online and target state dicts and its Adam state dict, as a plain
        torch.optim.Adam over its network's parameters would give them."""
        state = self.optimizer.states[k]
        step, moments = (None, []) if state is None else (
            state["step"], list(zip(self._split(state["exp_avg"]), self._split(state["exp_avg_sq"])))
        )
        optimizer = one_seed_state_dict(len(list(self.template.parameters())), self.optimizer.learning_rate, step, moments)
        return self.online[k].state_dict(), self.target[k].state_dict(), optimizer

    def load_seed_state(
        self, k: int, online: dict[str, torch.Tensor], target: dict[str, torch.Tensor], optimizer: dict[str, Any]
    ) -> None:
        """Write seed k's online and target weights and Adam state (`seed_state`'s layout, also
        that of every checkpoint a one-seed run wrote)."""
        self.online[k].load_state_dict(online)
        self.target[k].load_state_dict(target)
        saved = optimizer["state"]
        if not saved:
            self.optimizer.states[k] = None
            return
        count = len(list(self.template.parameters()))
        if sorted(saved) != list(range(count)):
            raise ValueError(f"the optimizer state holds parameters {sorted(saved)}, the network has {count}")
        steps = {float(entry["step"]) for entry in saved.values()}
        if len(steps) != 1:
            raise ValueError(f"the optimizer state's parameters have taken different step counts {sorted(steps)}")
        self.optimizer.states[k] = {
            "step": torch.tensor(steps.pop(), dtype=torch.float32, device=self.device),
            "exp_avg": self._join([saved[index]["exp_avg"] for index in range(count)]),
            "exp_avg_sq": self._join([saved[index]["exp_avg_sq"] for index in range(count)]),
        }

    def _split(self, row: torch.Tensor) -> list[torch.Tensor]:
        """A seed's flat row [P] -> its parameters' tensors, in `parameters()` order."""
        return [row[offset : offset + shape.numel()].view(shape) for offset, shape in parameter_slices(self.template).values()]

    def _join(self, parts: list[torch.Tensor]) -> torch.Tensor:
        """Inverse of `_split`: the parameters' tensors -> a flat row [P] on the device."""
        return torch.cat([part.reshape(-1) for part in parts]).to(self.device, torch.float32)

    def keep(self, indices: Sequence[int]) -> None:
        """Go on with the seeds at `indices` alone (the others stopped): their weights, targets,
        Adam states and generators as they are. `online` and `target` are new networks afterwards."""
        index = torch.tensor(list(indices), device=self.device, dtype=torch.int64)
        states = [self.optimizer.states[k] for k in indices]
        self.seeds = [self.seeds[k] for k in indices]
        self.generators = [self.generators[k] for k in indices]
        self._build(self.weights.index_select(0, index), self.target_weights.index_select(0, index), states)


def concatenate(batches: Sequence[ReplayBatch]) -> ReplayBatch:
    """S batches of R rows -> one of S * R rows, seed-major (the stacked networks' layout)."""
    if len(batches) == 1:
        return batches[0]

    def joined(key: str) -> dict[str, np.ndarray]:
        return {name: np.concatenate([getattr(batch, key)[name] for batch in batches]) for name in batches[0].observations}

    return ReplayBatch(
        joined("observations"),
        *(np.concatenate([getattr(batch, field) for batch in batches]) for field in ("actions", "rewards")),
        joined("next_observations"),
        *(np.concatenate([getattr(batch, field) for batch in batches]) for field in ("dones", "discounts")),
    )


def fractions(generators: Sequence[torch.Generator], rows: int, count: int, device: torch.device) -> torch.Tensor:
    """Quantile fractions [S * rows, count], seed-major, each seed's from its own CPU generator."""
    drawn = torch.cat([torch.rand(rows, count, generator=generator) for generator in generators])
    return drawn.to(device, non_blocking=True)


def td_losses(
    model: QNetwork,
    target: QNetwork,
    batch: ReplayBatch,
    learner: LearnerConfig,
    generators: Sequence[torch.Generator],
    trim: bool = True,
) -> torch.Tensor:
    """Each seed's quantile Huber loss (IQN heads) or Huber TD loss (`dqn`) of its batch: [S].

    `model` and `target` are stacked networks of S = len(generators) seeds and `batch` their
    rows seed-major (S * R). The online network runs as it is (train mode: dropout on); the
    target network, put in eval mode (train mode, its dropout on, with `learner.target_dropout`),
    gives R + gamma^k * (1 - done) * Z_target(s', a*) with a* its own argmax of the mean, or with
    `learner.double_dqn` the online network's argmax, or with `learner.max_per_fraction` its
    argmax at each fraction (quantile_td_target). `trim`
    cuts the slots empty in every row of the batch first (`trim_padding`: the same losses to
    float round-off, in less time); `learner.bf16` runs the networks under bfloat16 autocast,
    their heads' output layers and the loss in float32.
    """
    device = next(model.parameters()).device
    seeds = len(generators)
    observations, next_observations = batch.observations, batch.next_observations
    if trim:
        observations, next_observations = trim_padding(observations), trim_padding(next_observations)
    states, next_states = as_tensors(observations, device), as_tensors(next_observations, device)
    actions = torch.from_numpy(batch.actions).to(device)
    rewards, dones = torch.from_numpy(batch.rewards).to(device), torch.from_numpy(batch.dones).to(device)
    discounts = torch.from_numpy(batch.discounts).to(device)
    rows = len(actions) // seeds
    target.train(learner.target_dropout)
    with torch.autocast(device.type, dtype=torch.bfloat16, enabled=learner.bf16):
        if model.distributional:
            taus = fractions(generators, rows, learner.num_quantiles, device)
            quantiles = model(*states, taus).quantiles  # [S * R, N, A]
            index = actions[:, None, None].expand(-1, learner.num_quantiles, 1)
            taken = quantiles.gather(2, index).squeeze(2)  # [S * R, N]
            with torch.no_grad():
                next_taus = fractions(generators, rows, learner.num_target_quantiles, device)
                next_quantiles = target(*next_states, next_taus).quantiles
                best = model(*next_states, next_taus).quantiles.mean(dim=1).argmax(dim=1) if learner.double_dqn else None
                targets = quantile_td_target(rewards, dones, next_quantiles, discounts, best, learner.max_per_fraction)
            return quantile_huber_rows(taken, taus, targets).view(seeds, rows).mean(dim=1)
        q_values = model(*states).quantiles[:, 0]  # [S * R, A]
        taken = q_values.gather(1, actions[:, None]).squeeze(1)
        with torch.no_grad():
            best = model(*next_states).quantiles[:, 0].argmax(dim=1) if learner.double_dqn else None
            targets = td_target(rewards, dones, target(*next_states).quantiles[:, 0], discounts, best)
        return huber(taken - targets).view(seeds, rows).mean(dim=1)
