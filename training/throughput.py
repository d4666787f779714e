"""How fast the training loop's two halves run on this machine: `python -m training bench`.

`benchmark` times pure rollouts (collect and store, no learning) on every scenario of a run
and pure updates on each scenario's transitions, in each UPDATE_MODES entry, and estimates
the run's wall clock from them. It drives the loop's own helpers (training/train.py), so
what it times is what a run does.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch

from terl_rt.sim.rollout import Rollout
from terl_rt.sim.scenario import CURRICULUM_STARTS, CURRICULUM_STEPS, Scenario
from terl_rt.sim.world import World
from training.buffer import ReplayBuffer
from training.config import CURRICULUM_STAGES, Config, LearnerConfig
from training.networks import QNetwork
from training.train import TransitionStore, buffer_evader_slots, build_learner, epsilon_greedy, learn

UPDATE_MODES = ("fp32 full", "fp32 trimmed", "bf16 trimmed")
"""How `benchmark` times updates: float32 on the buffer's full rows (the loop before trimming;
TERL's transformer layers still skip padded tokens, `ValidTokens`, since 1350b49, so this
baseline is about 1.65x what it was before then), float32 with the empty slots trimmed
(`trim_padding`), and trimmed under bfloat16 autocast."""


@dataclass(frozen=True)
class Throughput:
    """Speed of the loop's two halves on this machine, and what they imply for a run."""

    model: str
    hidden: int
    layers: int
    heads: int
    num_envs: int
    threads: int
    rollout_steps_per_second: dict[str, float]
    """per scenario: environment steps/s of collect + store (no learning), random weights."""
    update_modes: dict[str, dict[str, float]]
    """per scenario, per UPDATE_MODES entry: gradient updates/s at config.batch_size (sample,
    forward, backward, Adam step) on a buffer of that scenario's transitions."""
    mix_updates_per_second: dict[str, float]
    """per UPDATE_MODES entry: updates/s over the run's mix of scenarios (each scenario's share
    of the steps, so of the updates)."""
    updates_per_second: float
    """updates/s over the mix in the config's own mode (trimmed; bf16 when config.bf16)."""
    estimated_hours: float
    """wall clock of config.total_steps: rollout time per stage plus the updates due."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def benchmark(config: Config, seconds: float = 5.0) -> Throughput:
    """Time pure rollouts on every scenario of the run, then pure updates at batch
    `config.batch_size` on each scenario's transitions in every UPDATE_MODES entry.

    Each rollout measurement runs for about `seconds` after a short warm-up, each update
    measurement for about `seconds` / 3; the modes take turns on the same sampled batches. The
    estimate weights each stage's rollout and update speeds by its share of `config.total_steps`
    and counts (total_steps - learning_starts) / train_frequency updates. The caller sets torch's
    thread count.
    """
    network, learner, schedule = config.network, config.learner, config.schedule
    rng = np.random.default_rng(config.run.seed)
    torch.manual_seed(config.run.seed)
    model, target, optimizer = build_learner(network, learner)

    # Scenarios of the run with their shares of the steps.
    if schedule.curriculum:
        starts = [start / CURRICULUM_STEPS for start, _ in CURRICULUM_STARTS] + [1.0]
        shares = {name: end - start for name, start, end in zip(CURRICULUM_STAGES, starts, starts[1:])}
    else:
        names = (schedule.scenario, *schedule.mixed_scenarios)
        shares = {name: 1.0 / len(names) for name in names}
    slots = buffer_evader_slots([Scenario.preset(name) for name in shares])

    rates, modes = {}, {}
    for name in shares:
        # Every scenario's transitions in a buffer of the run's row width, as training stores them.
        buffer = ReplayBuffer(max(learner.batch_size * 64, 10_000), slots)
        scenario = Scenario.preset(name).replace(reward=config.data.reward)
        rollout = Rollout(World(scenario, schedule.num_envs, seed=config.run.seed))
        transitions = TransitionStore(buffer, config.data, learner.gamma, schedule.num_envs * scenario.pursuers)
        timed_steps, start = -3, time.perf_counter()  # three untimed warm-up batch steps
        while timed_steps <= 0 or time.perf_counter() - start < seconds:
            if timed_steps == 0:
                start = time.perf_counter()
            turn = rollout.turn()
            states = turn.observation.rows(turn.rows).as_inputs()
            step = rollout.step(epsilon_greedy(model, states, schedule.start_e, rng))
            transitions.add(turn.rows, states, step.actions, step.observation, step.result, rng)
            timed_steps += 1
        rates[name] = timed_steps * schedule.num_envs / (time.perf_counter() - start)
        modes[name] = time_updates(model, target, optimizer, buffer, learner, rng, seconds / 3)

    mix = {mode: 1.0 / sum(share / modes[name][mode] for name, share in shares.items()) for mode in UPDATE_MODES}
    own = mix["bf16 trimmed" if learner.bf16 else "fp32 trimmed"]
    rollout_seconds = sum(share * schedule.total_steps / rates[name] for name, share in shares.items())
    update_count = max(schedule.total_steps - config.data.learning_starts, 0) / learner.train_frequency
    return Throughput(
        model=network.model,
        hidden=network.hidden,
        layers=network.layers,
        heads=network.heads,
        num_envs=schedule.num_envs,
        threads=torch.get_num_threads(),
        rollout_steps_per_second=rates,
        update_modes=modes,
        mix_updates_per_second=mix,
        updates_per_second=own,
        estimated_hours=(rollout_seconds + update_count / own) / 3600.0,
    )


def time_updates(
    model: QNetwork,
    target: QNetwork,
    optimizer: torch.optim.Optimizer,
    buffer: ReplayBuffer,
    learner: LearnerConfig,
    rng: np.random.Generator,
    seconds: float,
) -> dict[str, float]:
    """Updates/s of each UPDATE_MODES entry on batches of `buffer`, the modes taking turns on
    the same batches until each has run for about `seconds` (after one warm-up update each)."""
    settings = {mode: (mode != "fp32 full", dataclasses.replace(learner, bf16=mode.startswith("bf16"))) for mode in UPDATE_MODES}
    elapsed = dict.fromkeys(UPDATE_MODES, 0.0)
    counts = dict.fromkeys(UPDATE_MODES, -1)  # the first update of each mode is a warm-up
    while min(counts.values()) < 3 or min(elapsed.values()) < seconds:
        batch = buffer.sample(learner.batch_size, rng)
        for mode, (trim, mode_learner) in settings.items():
            start = time.perf_counter()
            learn(model, target, optimizer, batch, mode_learner, trim)
            if counts[mode] >= 0:
                elapsed[mode] += time.perf_counter() - start
            counts[mode] += 1
    return {mode: counts[mode] / elapsed[mode] for mode in UPDATE_MODES}
