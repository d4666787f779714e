"""How fast the training loop's two halves run on this machine: `python -m training bench`.

`benchmark` times pure rollouts (collect and store, no learning) on every scenario of a run, then
the update on each scenario's transitions: the one-seed update as main 7725bd1 made it (a plain
network, clip_grad_norm_ and a per-parameter Adam: `PlainLearner`) beside the `Learner` of S seeds
trained together, for each S asked, the variants taking turns on the same sampled batches. It
counts the aten calls and the matrix-product GFLOP of one update of each, and measures the
machine's own matrix-product rate first (these machines differ: some have AVX-512 and bf16, some
AVX2 only), so a figure says what share of this machine it uses. Times are CPU seconds of this
process (`time.process_time`: other processes' load does not count), or wall seconds on a GPU.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch
from torch.profiler import ProfilerActivity, profile
from torch.utils.flop_counter import FlopCounterMode

from terl_rt.sim.rollout import Rollout
from terl_rt.sim.scenario import CURRICULUM_STARTS, CURRICULUM_STEPS, Scenario
from terl_rt.sim.world import World
from training.acting import TransitionStore, epsilon_greedy
from training.buffer import ReplayBatch, ReplayBuffer
from training.config import CURRICULUM_STAGES, Config
from training.learner import Learner, td_losses
from training.networks import network_from_config
from training.seed_state import buffer_evader_slots

PLAIN = "one seed (7725bd1)"
"""The name of the one-seed update as main 7725bd1 made it, the baseline of every ratio."""
MATMUL_SIZE = 1024
"""Side of the square float32 matrices whose product measures the machine's matrix-product rate."""


@dataclass(frozen=True)
class UpdateSpeed:
    """One update variant over the run's mix of scenarios."""

    name: str
    """PLAIN, or "S seeds" (a Learner of S seeds trained together)."""
    seeds: int
    updates_per_second: float
    """updates of each seed per CPU second (the stack's updates: every seed takes one each)."""
    seed_updates_per_second: float
    """updates per CPU second counted over the seeds: seeds x updates_per_second."""
    aten_calls: float
    """aten operator calls of one update (every level, as torch.profiler counts them), over the mix."""
    gflop: float
    """GFLOP of matrix products in one update (torch.utils.flop_counter), over the mix."""
    matmul_share: float
    """gflop x updates_per_second against the machine's matrix-product rate."""


@dataclass(frozen=True)
class Throughput:
    """Speed of the loop's two halves on this machine, and what they imply for a run."""

    model: str
    hidden: int
    layers: int
    heads: int
    num_envs: int
    threads: int
    device: str
    cpu_capability: str
    """the vector instructions torch uses here (torch.backends.cpu.get_cpu_capability: AVX2, AVX512, ...)."""
    matmul_gflops: float
    """float32 GFLOP per second of one MATMUL_SIZE x MATMUL_SIZE product, as measured at start."""
    rollout_steps_per_second: dict[str, float]
    """per scenario: environment steps per CPU second of collect + store (no learning), random weights."""
    updates: list[UpdateSpeed]
    """PLAIN first, then each S asked."""
    estimated_hours: dict[str, float]
    """per update variant: CPU hours of config.total_steps for every seed of it (rollouts of each
    seed and the updates due), divided by its seeds: the cost of one seed."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def run_shares(config: Config) -> dict[str, float]:
    """The scenarios of the run with their shares of its steps (the curriculum's stages, or the
    fixed preset and its mixed ones)."""
    schedule = config.schedule
    if schedule.curriculum:
        starts = [start / CURRICULUM_STEPS for start, _ in CURRICULUM_STARTS] + [1.0]
        return {name: end - start for name, start, end in zip(CURRICULUM_STAGES, starts, starts[1:])}
    names = (schedule.scenario, *schedule.mixed_scenarios)
    return {name: 1.0 / len(names) for name in names}


def matmul_gflops(seconds: float = 1.0) -> float:
    """This machine's float32 matrix-product rate (GFLOP per CPU second) on the torch threads set."""
    a, b = torch.randn(MATMUL_SIZE, MATMUL_SIZE), torch.randn(MATMUL_SIZE, MATMUL_SIZE)
    torch.mm(a, b)
    count, start = 0, time.process_time()
    while count < 3 or time.process_time() - start < seconds:
        torch.mm(a, b)
        count += 1
    return 2 * MATMUL_SIZE**3 * count / (time.process_time() - start) / 1e9


class PlainLearner:
    """One seed's learner as main 7725bd1 made it, the reference of the stacked `Learner`: a plain
    network and its target, a per-parameter torch.optim.Adam, clip_grad_norm_ over the parameters,
    quantile fractions from `generator`. Built as a one-seed run builds it (torch seeded `seed`)."""

    def __init__(self, config: Config, seed: int) -> None:
        self.config = config.learner
        torch.manual_seed(seed)
        self.model = network_from_config(config.network).to(config.learner.device)
        self.target = network_from_config(config.network).to(config.learner.device)
        self.target.load_state_dict(self.model.state_dict())
        self.target.eval().requires_grad_(False)
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=config.learner.learning_rate)
        self.generator = torch.Generator()
        self.generator.set_state(torch.get_rng_state())

    def update(self, batches: list[ReplayBatch]) -> float:
        """One update on `batches[0]`; returns the loss."""
        self.model.train()
        loss = td_losses(self.model, self.target, batches[0], self.config, [self.generator])[0]
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.config.max_grad_norm)
        self.optimizer.step()
        return loss.item()


def benchmark(config: Config, seeds: Sequence[int] = (1, 2, 3, 4), seconds: float = 5.0) -> Throughput:
    """Time pure rollouts on every scenario of the run, then the update on each scenario's
    transitions: `PLAIN` and a Learner of S seeds for each S in `seeds`, taking turns on the same
    batches until each has run for about `seconds` / 3 a scenario.

    Each rollout measurement runs for about `seconds` after a short warm-up. Rates over the mix
    weight each scenario by its share of the steps. The caller sets torch's thread count.
    """
    network, learner, schedule = config.network, config.learner, config.schedule
    rng = np.random.default_rng(config.run.seed)
    torch.manual_seed(config.run.seed)
    gflops = matmul_gflops()
    shares = run_shares(config)
    slots = buffer_evader_slots([Scenario.preset(name) for name in shares])
    variants: dict[str, tuple[int, Callable[[list[ReplayBatch]], Any]]] = {PLAIN: (1, PlainLearner(config, 1).update)}
    for count in seeds:
        stack = Learner(network, learner, list(range(1, count + 1)))
        variants[f"{count} seeds"] = (count, stack.update)
    actor = network_from_config(network).to(learner.device)
    most = max(count for count, _ in variants.values())

    rates: dict[str, float] = {}
    per_scenario: dict[str, dict[str, tuple[float, float, float]]] = {}
    for name in shares:
        # Every scenario's transitions in a buffer of the run's row width, as training stores them.
        buffer = ReplayBuffer(max(learner.batch_size * 64, 10_000), slots)
        scenario = Scenario.preset(name).replace(reward=config.data.reward)
        rollout = Rollout(World(scenario, schedule.num_envs, seed=config.run.seed))
        transitions = TransitionStore(buffer, config.data, learner.gamma, schedule.num_envs * scenario.pursuers)
        timed_steps, start = -3, time.process_time()  # three untimed warm-up batch steps
        while timed_steps <= 0 or time.process_time() - start < seconds:
            if timed_steps == 0:
                start = time.process_time()
            turn = rollout.turn()
            states = turn.observation.rows(turn.rows).as_inputs()
            step = rollout.step(epsilon_greedy(actor, states, schedule.start_e, rng, learner.random_acting_fractions))
            transitions.add(turn.rows, states, step.actions, step.observation, step.result, rng)
            timed_steps += 1
        rates[name] = timed_steps * schedule.num_envs / (time.process_time() - start)
        per_scenario[name] = time_variants(variants, buffer, learner.batch_size, most, rng, seconds / 3)

    updates = []
    for variant, (count, _) in variants.items():
        # The mix: time per update is the share-weighted mean of each scenario's.
        seconds_each = sum(share / per_scenario[name][variant][0] for name, share in shares.items())
        calls = sum(share * per_scenario[name][variant][1] for name, share in shares.items())
        flops = sum(share * per_scenario[name][variant][2] for name, share in shares.items())
        updates.append(UpdateSpeed(
            name=variant, seeds=count, updates_per_second=1.0 / seconds_each, seed_updates_per_second=count / seconds_each,
            aten_calls=calls, gflop=flops, matmul_share=flops / seconds_each / gflops,
        ))
    rollout_seconds = sum(share * schedule.total_steps / rates[name] for name, share in shares.items())
    update_count = max(schedule.total_steps - config.data.learning_starts, 0) / learner.train_frequency
    return Throughput(
        model=network.model, hidden=network.hidden, layers=network.layers, heads=network.heads,
        num_envs=schedule.num_envs, threads=torch.get_num_threads(), device=learner.device,
        cpu_capability=torch.backends.cpu.get_cpu_capability(), matmul_gflops=gflops,
        rollout_steps_per_second=rates, updates=updates,
        estimated_hours={
            speed.name: (rollout_seconds + update_count / speed.updates_per_second / speed.seeds) / 3600.0
            for speed in updates
        },
    )


def time_variants(
    variants: dict[str, tuple[int, Callable[[list[ReplayBatch]], Any]]], buffer: ReplayBuffer, batch_size: int,
    most: int, rng: np.random.Generator, seconds: float,
) -> dict[str, tuple[float, float, float]]:
    """Per variant: (updates per CPU second, aten calls of one update, GFLOP of one update), the
    variants taking turns on the same batches (`most` of them drawn a round) until each has
    run for about `seconds` (after one warm-up update each)."""
    elapsed = dict.fromkeys(variants, 0.0)
    counts = dict.fromkeys(variants, -1)  # the first update of each is a warm-up
    while min(counts.values()) < 3 or min(elapsed.values()) < seconds:
        batches = [buffer.sample(batch_size, rng) for _ in range(most)]
        for name, (count, update) in variants.items():
            start = time.process_time()
            update(batches[:count])
            if counts[name] >= 0:
                elapsed[name] += time.process_time() - start
            counts[name] += 1
    batches = [buffer.sample(batch_size, rng) for _ in range(most)]
    return {
        name: (counts[name] / elapsed[name], *update_cost(update, batches[:count]))
        for name, (count, update) in variants.items()
    }


def update_cost(update: Callable[[list[ReplayBatch]], Any], batches: list[ReplayBatch]) -> tuple[float, float]:
    """(aten operator calls, GFLOP of matrix products) of one call of `update` on `batches`."""
    with profile(activities=[ProfilerActivity.CPU]) as profiler:
        update(batches)
    calls = sum(event.count for event in profiler.key_averages() if event.key.startswith("aten::"))
    with FlopCounterMode(display=False) as counter:
        update(batches)
    return float(calls), counter.get_total_flops() / 1e9
