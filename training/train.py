"""Training of a pursuer Q-network: IQN (or DQN) with a shared network for every pursuer.

Centralised training, decentralised execution (policy.md section 2): B worlds are
stepped together; one batched forward of the online network (or of its copy refreshed every
`LearnerConfig.actor_update_frequency` steps) chooses the action of
every active pursuer of every world (epsilon-greedy per pursuer), and every active
pursuer's transition goes into one replay buffer. With `ScheduleConfig.mixed_scenarios` there is a
group of B worlds per scenario (`WorldGroup`) and the batch steps go to the groups in turn,
all into the one buffer (rows padded to the most evader slots).

Seeds trained together (`train_seeds`): S seeds share the loop and its schedule and one
`Learner` (training/learner.py: one batched update for all, each seed exactly itself); each
seed keeps its own worlds, replay buffer, generator, snapshots, checkpoints and metrics in its
own folder (`SeedState`), as a one-seed run (`train`, S = 1) keeps them.

Counting: an environment step is one step of one world, so a batch step is B
environment steps; `total_steps`, `learning_starts`, `train_frequency`,
`target_network_frequency` and the logging, snapshot and checkpoint intervals
are all in environment steps. A batch step runs one gradient update per multiple
of `train_frequency` it crosses, which keeps the published ratio (one update of
128 rows per 4 environment steps) for any B. The target network is copied whole every
`target_network_frequency` steps; the step size may fall linearly to the end of the run
(`LearnerConfig.final_learning_rate`).

How a pursuer acts and what it stores is training/acting.py's; a seed's own worlds, buffer and
records, and the metrics.jsonl they write, are training/seed_state.py's (`SeedState`).

`train_seeds` is the loop, read top to bottom; the helpers before it do one thing each.
training/lab/throughput.py times the loop's two halves (rollout, update) apart.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from training.checkpoint import Counters
from training.config import Config, LearnerConfig
from training.learner import Learner
from training.losses import linear_schedule
from training.seed_state import (
    Progress, SeedFailed, SeedRun, SeedState, recent_means, stage_label, training_scenarios,
)
from training.stops import StopRequests, TrainingStopped


# ---------------------------------------------------------------- schedules
def crossings(before: int, after: int, every: int) -> int:
    """How many multiples of `every` lie in (before, after]: events due in a batch step."""
    return after // every - before // every


def learning_rate_at(learner: LearnerConfig, total_steps: int, env_step: int) -> float:
    """Adam's step size at `env_step`: `learning_rate`, or with `final_learning_rate` its linear
    fall from `decay_start` to `total_steps`."""
    if not learner.final_learning_rate:
        return learner.learning_rate
    return linear_schedule(
        learner.learning_rate, learner.final_learning_rate,
        total_steps - learner.decay_start, env_step - learner.decay_start,
    )


# ---------------------------------------------------------------- display
def progress_line(seeds: list[SeedState], env_step: int, total_steps: int, rate: float, epsilon: float,
                  stage_name: str) -> str:
    """The status line: steps, speed, and each seed's success over its recent episodes and last loss."""
    def success(seed: SeedState) -> str:
        value = recent_means(seed.recent)["success_rate"]
        return "-" if value is None else f"{value:.2f}"

    losses = "/".join("-" if seed.last_loss is None else f"{seed.last_loss:.3g}" for seed in seeds)
    seed_names = "" if len(seeds) == 1 else f"seeds {'/'.join(str(seed.seed) for seed in seeds)} | "
    return (
        f"step {env_step:,}/{total_steps:,} | {rate:,.0f} steps/s | {seed_names}"
        f"episodes {'/'.join(str(seed.counters.episodes) for seed in seeds)} | "
        f"success {'/'.join(success(seed) for seed in seeds)} | loss {losses} | "
        f"eps {epsilon:.3f} | updates {seeds[0].counters.updates} | {stage_name}"
    )


# ---------------------------------------------------------------- the loop's parts
def resumed_step(seeds: list[SeedState]) -> int:
    """The environment step the seeds start from: seeds trained together share one schedule, so
    they resume from one step (ValueError otherwise)."""
    steps = {seed.seed: seed.counters.env_step for seed in seeds}
    if len(set(steps.values())) != 1:
        raise ValueError(f"seeds trained together resume from one environment step; these are at {steps}")
    return seeds[0].counters.env_step


class Refill:
    """A resume's refill of the seeds' replay buffers (`restore_buffer`), at the environment step
    it stopped, as if it had never stopped: its steps do not count toward the schedule (stage,
    epsilon, step size), and no update runs until it ends."""

    def __init__(self, seeds: list[SeedState], num_envs: int, learning_starts: int) -> None:
        self.active = any(seed.refill_to for seed in seeds)
        self.num_envs = num_envs
        self.learning_starts = learning_starts
        self.steps = 0
        """environment steps refilled so far."""

    def advance(self, seeds: list[SeedState], env_step: int, progress: Progress) -> None:
        """Count a batch step of the refill; it ends once every seed's buffer holds what it owes
        (`SeedState.refill_to`, then cleared) and `learning_starts` steps have been refilled."""
        self.steps += self.num_envs
        if all(len(seed.buffer) >= seed.refill_to for seed in seeds) and self.steps >= self.learning_starts:
            self.active = False
            for seed in seeds:
                seed.refill_to = 0
            progress.note(f"environment step {env_step}: refilled in {self.steps:,} steps, updates resume")


def update_seeds(
    learner: Learner, seeds: list[SeedState], due: int, batch_size: int, env_step: int, progress: Progress
) -> list[SeedState]:
    """`due` gradient updates, each one `Learner.update` of every seed on a batch of its own
    buffer; each seed keeps its losses. A seed whose loss turned non-finite stops (`stop_seeds`).
    Returns the seeds that go on."""
    losses = torch.stack([
        learner.update([seed.buffer.sample(batch_size, seed.rng) for seed in seeds]) for _ in range(due)
    ]).T.tolist()  # [S][due]: one read of the device a batch step
    for seed, seed_losses in zip(seeds, losses):
        seed.losses.extend(seed_losses)
        seed.last_loss = seed_losses[-1]
        seed.counters.updates += due
    failed = [k for k, seed_losses in enumerate(losses) if not np.isfinite(seed_losses).all()]
    return stop_seeds(failed, seeds, learner, env_step, progress) if failed else seeds


def stop_seeds(
    failed: list[int], seeds: list[SeedState], learner: Learner, env_step: int, progress: Progress
) -> list[SeedState]:
    """Stop the seeds at indices `failed` (a non-finite loss): one line each, their last
    checkpoints stay; the others go on (the learner keeps them alone) and are returned.
    SeedFailed when none is left."""
    for k in failed:
        progress.note(
            f"Error: seed {seeds[k].seed}: a non-finite loss at environment step {env_step:,}; it stops here, "
            f"its last checkpoint in {seeds[k].out_dir} stays" + ("" if len(failed) == len(seeds) else "; the other seeds go on")
        )
    kept = [k for k in range(len(seeds)) if k not in failed]
    if not kept:
        progress.close()
        raise SeedFailed(f"every seed stopped on a non-finite loss at environment step {env_step:,}")
    learner.keep(kept)
    return [seeds[k] for k in kept]


def refresh_progress(progress: Progress, seeds: list[SeedState], env_step: int, total_steps: int, refilling: bool,
                     finished: bool, epsilon: float, stage_name: str) -> None:
    """Rewrite the status line when it is due: the refill's progress while a resume refills,
    else `progress_line` (also at the end)."""
    if progress.due() and refilling:
        progress.steps_per_second(env_step)  # starts the next refresh window
        held = "/".join(f"{len(seed.buffer):,}/{seed.refill_to:,}" for seed in seeds)
        progress.show(f"step {env_step:,}: refilling the replay buffer, {held} transitions")
    elif progress.due() or finished:
        rate = progress.steps_per_second(env_step)
        progress.show(progress_line(seeds, env_step, total_steps, rate, epsilon, stage_name))


def checkpoint_seeds(seeds: list[SeedState], learner: Learner, env_step: int, progress: Progress,
                     stopping: bool = False) -> None:
    """Every seed's checkpoint in its own folder (`SeedState.checkpoint`; `stopping`: the one a stop writes)."""
    for k, seed in enumerate(seeds):
        progress.show(f"step {env_step:,}: {seed.label}checkpoint ({len(seed.buffer):,} transitions)")
        seed.checkpoint(learner, k, stopping=stopping)


# ---------------------------------------------------------------- the loop
def train(
    config: Config,
    out_dir: str | Path,
    resume: str | Path | None = None,
    show_progress: bool = True,
    load_replay: bool = True,
) -> Counters:
    """Train the config's network (seed `config.run.seed`) for its schedule's `total_steps`
    environment steps into `out_dir`; return the final counters. See `train_seeds`."""
    run = SeedRun(config.run.seed, Path(out_dir), None if resume is None else Path(resume))
    return train_seeds(config, [run], show_progress, load_replay)[config.run.seed]


def train_seeds(
    config: Config, runs: list[SeedRun], show_progress: bool = True, load_replay: bool = True
) -> dict[int, Counters]:
    """Train the config's network for each seed of `runs` at once (seeds trained together, one
    `Learner`), for the schedule's `total_steps` environment steps; return each seed's final
    counters by seed.

    Each seed writes into its own folder what a one-seed run writes: metrics.jsonl, the
    checkpoint files (training.checkpoint), the replay buffer (replay.npz,
    `DataConfig.save_replay`) and the best snapshot (best/, `RunConfig.snapshot_frequency`).
    A seed that resumes continues its checkpoint's weights, optimizer, counters, RNG states
    and, when it was saved there, replay buffer (`restore_buffer`; `load_replay` false refills
    it instead); seeds trained together share one schedule, so they resume from one
    environment step. A seed whose loss turns non-finite stops with one line (its last
    checkpoint stays) and the others go on; SeedFailed when none is left. SIGINT (Ctrl-C) or
    SIGTERM ends the batch step, writes every seed's checkpoint and raises TrainingStopped.
    The caller sets torch's thread count.
    """
    learner_config, data, schedule, run = config.learner, config.data, config.schedule, config.run
    if len({run.seed for run in runs}) != len(runs):
        raise ValueError(f"train_seeds: the seeds {[run.seed for run in runs]} repeat one")
    progress = Progress(show_progress)

    # --- seeding, networks and each seed's state (its generators, counters and replay buffer)
    learner = Learner(config.network, learner_config, [run.seed for run in runs])
    seeds = [SeedState(run, config, learner, k, load_replay, progress, many=len(runs) > 1) for k, run in enumerate(runs)]
    env_step = resumed_step(seeds)
    learner.refresh_actors()  # a resumed acting copy starts from the loaded weights
    progress.last_step, progress.last_time = env_step, time.perf_counter()  # the speed counts from here
    stage_name = stage_label(training_scenarios(schedule, data.reward, env_step))
    for seed in seeds:
        seed.enter_stage(training_scenarios(schedule, data.reward, env_step), announce=False)
    num_envs = schedule.num_envs
    session_start, session_step = time.perf_counter(), env_step
    refill = Refill(seeds, num_envs, data.learning_starts)  # a resume without its buffers refills them first

    with StopRequests() as stops:
        while env_step < schedule.total_steps:
            # --- curriculum: a new stage gets new worlds; episodes under way are dropped
            stage = training_scenarios(schedule, data.reward, env_step)
            if stage_label(stage) != stage_name:
                stage_name = stage_label(stage)
                for seed in seeds:
                    seed.enter_stage(stage, announce=True)
                progress.note(f"environment step {env_step}: stage {stage_name}")
            group_index = (env_step + refill.steps) // num_envs % len(stage)

            # --- collect and store: every seed's worlds, each acted by its own network
            epsilon = linear_schedule(
                schedule.start_e, schedule.end_e, schedule.exploration_fraction * schedule.total_steps, env_step
            )
            learning_rate = learning_rate_at(learner_config, schedule.total_steps, env_step)
            learner.set_learning_rate(learning_rate)
            for actor, seed in zip(learner.actors, seeds):
                seed.collect(actor, group_index, epsilon)
            previous_step = env_step
            if refill.active:  # the schedule waits for the refill's steps
                refill.advance(seeds, env_step, progress)
            else:
                env_step += num_envs
                for seed in seeds:
                    seed.counters.env_step = env_step

            # --- learn: the updates due in this batch step (one call for every seed), then the target copy
            if not refill.active and env_step >= data.learning_starts and min(len(seed.buffer) for seed in seeds) >= learner_config.batch_size:
                # Updates for the environment steps after learning_starts: (T - learning_starts) / 4 in all.
                due = crossings(max(previous_step, data.learning_starts), env_step, learner_config.train_frequency)
                if due:
                    seeds = update_seeds(learner, seeds, due, learner_config.batch_size, env_step, progress)
                if crossings(previous_step, env_step, learner_config.target_network_frequency):
                    learner.copy_target()
            if crossings(previous_step, env_step, learner_config.actor_update_frequency or schedule.total_steps + 1):
                learner.refresh_actors()

            # --- evaluate, snapshot and log, seed by seed
            finished = env_step >= schedule.total_steps
            session_seconds = time.perf_counter() - session_start
            for k, seed in enumerate(seeds):
                seed.counters.wall_seconds = seed.wall_before + session_seconds
                if run.snapshot_frequency and (crossings(previous_step, env_step, run.snapshot_frequency) or finished):
                    seed.snapshot(learner, k, progress)
                if finished or crossings(previous_step, env_step, run.log_frequency):
                    seed.log_train(epsilon, learning_rate, stage_name, env_step - session_step, session_seconds)
            refresh_progress(progress, seeds, env_step, schedule.total_steps, refill.active, finished, epsilon, stage_name)

            # --- checkpoint every seed (the replay buffer first: state.json, written last, marks a whole checkpoint)
            stopping = stops.received is not None
            if finished or stopping or crossings(previous_step, env_step, run.checkpoint_frequency):
                checkpoint_seeds(seeds, learner, env_step, progress, stopping)
            if stopping:
                progress.close()
                raise TrainingStopped(stops.received, env_step, [seed.out_dir for seed in seeds])

    progress.close()
    return {seed.seed: seed.counters for seed in seeds}
