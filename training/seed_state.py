"""One seed's part of a run (`SeedState`): its config, folder, generator, counters, replay
buffer, worlds and records, laid out as a one-seed run lays them out. The loop
(training/train.py) steps every seed's state together; the `Learner` holds their networks.

metrics.jsonl holds one JSON object a line, told apart by "kind":
- "train" (every `log_frequency` steps, at each evaluation and at the end): env_step,
  episodes, updates, stage, epsilon, learning_rate, loss (mean since the last record), success_rate,
  mean_return (per pursuer: the episode's summed rewards / N), return_terms (the
  same split by reward term), team_cooperation (the team-wide share of return_terms'
  cooperation, paid to every pursuer alike), collision_ratio and episode_steps over the last
  100 episodes, steps_per_second (this session), wall_seconds (all sessions);
- "stage": env_step and the curriculum stage that starts there;
- "resume": env_step and how the replay buffer was restored (loaded, or refilled);
- "snapshot": env_step, the greedy evaluations of a snapshot (current stage and
  `RunConfig.snapshot_preset`, run by terl_rt.evaluation as `terl-rt eval` runs them), its
  score and whether it became the best (kept in best/; with `RunConfig.keep_snapshots` every
  snapshot's network is kept in snapshots/<env_step>/).
"""

from __future__ import annotations

import json
import sys
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from terl_rt.evaluation.evaluate import evaluate_policy
from terl_rt.sim.reward import REWARD_TERMS
from terl_rt.sim.scenario import Scenario, curriculum_stage
from training.acting import WorldGroup, epsilon_greedy
from training.buffer import ReplayBuffer
from training.checkpoint import (
    Counters, TrainingState, load_checkpoint, read_config, restore_rng_states, rng_states, save_checkpoint,
    save_snapshot,
)
from training.config import RETURN_FIELDS, SNAPSHOT_FIELDS, Config, RunConfig, ScheduleConfig, changed_fields
from training.learner import Learner
from training.networks import QNetwork
from training.torch_policy import TorchPolicy

REPLAY_FILE = "replay.npz"
"""The saved replay buffer, beside the checkpoint files (DataConfig.save_replay)."""
BEST_FOLDER = "best"
"""Subfolder of the run holding the best snapshot so far, as a checkpoint."""
SNAPSHOTS_FOLDER = "snapshots"
"""Subfolder of the run holding every snapshot's online network by environment step (RunConfig.keep_snapshots)."""


def snapshot_folder(run: Path, env_step: int) -> Path:
    """Where a run keeps its snapshot of environment step `env_step`: RUN/snapshots/<step>/."""
    return run / SNAPSHOTS_FOLDER / str(env_step)


RECENT_EPISODES = 100
"""Finished episodes behind the success rate and mean return of the progress line and log."""
PROGRESS_SECONDS = 1.0
"""Seconds between refreshes of the progress line."""
METRICS_FILE = "metrics.jsonl"
"""Name of the JSON-lines log in the output folder."""


# ---------------------------------------------------------------- schedules
def training_scenarios(schedule: ScheduleConfig, reward: str, env_step: int) -> list[Scenario]:
    """The scenarios trained on at `env_step`: the curriculum stage (terl_rt.sim.scenario.
    curriculum_stage over `curriculum_steps`, else `total_steps`), or the fixed preset and
    `mixed_scenarios`, with the reward variant `reward`, the schedule's evader and the training
    episode limit."""
    if schedule.curriculum:
        scenarios = [curriculum_stage(env_step, schedule.curriculum_steps or schedule.total_steps)]
    else:
        scenarios = [Scenario.preset(name) for name in (schedule.scenario, *schedule.mixed_scenarios)]
    return [
        scenario.replace(reward=reward, evader=schedule.evader, max_steps=schedule.train_max_steps)
        for scenario in scenarios
    ]


def stage_label(scenarios: list[Scenario]) -> str:
    """What a run trains on at once, as logged: the scenarios' names (with the evader where it is
    not the paper's, `Scenario.label`) joined by '+'."""
    return "+".join(scenario.label for scenario in scenarios)


def buffer_evader_slots(scenarios: list[Scenario]) -> int:
    """Evader slots of the replay buffer rows: the most of the scenarios (the others are padded)."""
    return max(scenario.evader_slots for scenario in scenarios)


# ---------------------------------------------------------------- evaluation
SNAPSHOT_FIELDS_KEPT = ("name", "episodes", "seed", "success_rate", "travel_time_s_mean", "collision_ratio_mean", "steps_mean")
"""What a snapshot record keeps of each terl_rt.evaluation result (ScenarioResult.to_dict)."""


def greedy_evaluation(model: QNetwork, scenario: Scenario, run: RunConfig) -> dict[str, Any]:
    """`run.snapshot_episodes` greedy episodes of `scenario` through terl_rt.evaluation (the
    network behind a TorchPolicy), episode k with seed `run.eval_seed` + k as `terl-rt eval
    --seed` runs it, truncated after `run.eval_max_steps` steps. Returns the scenario name,
    episodes, first seed, success rate, travel time (s), collision ratio and steps."""
    result = evaluate_policy(TorchPolicy(model), scenario, run.snapshot_episodes, run.eval_seed, run.eval_max_steps)
    row = result.to_dict()
    return {("scenario" if key == "name" else key): row[key] for key in SNAPSHOT_FIELDS_KEPT}


def snapshot_score(evaluations: list[dict[str, Any]], run: RunConfig) -> float:
    """How good a snapshot is, higher is better: the mean over its evaluations of
    success rate - collision ratio - travel time / the evaluation's time limit.

    Success dominates (an extra encircled episode in 8 is worth 0.125); among equally
    successful snapshots, fewer collisions and shorter episodes win.
    """
    limit = run.eval_max_steps * 0.5  # s: the decision step is 0.5 s
    return float(np.mean([
        e["success_rate"] - e["collision_ratio_mean"] - e["travel_time_s_mean"] / limit for e in evaluations
    ]))


def take_snapshot(model: QNetwork, scenario: Scenario, run: RunConfig, best: float | None) -> tuple[dict[str, Any], bool]:
    """Evaluate the online network on the current stage `scenario` and `run.snapshot_preset` (both
    against the stage's evader); returns the "snapshot" record (without env_step) and whether it
    beats `best`."""
    preset = Scenario.preset(run.snapshot_preset).replace(evader=scenario.evader)
    evaluations = [greedy_evaluation(model, scenario, run), greedy_evaluation(model, preset, run)]
    score = snapshot_score(evaluations, run)
    better = best is None or score > best
    return {"kind": "snapshot", "score": score, "best": better, "evaluations": evaluations}, better


# ---------------------------------------------------------------- display and log
class Progress:
    """One status line on a text stream, rewritten in place with a carriage return."""

    def __init__(self, enabled: bool, env_step: int = 0, stream: TextIO | None = None) -> None:
        self.enabled = enabled
        self.stream = sys.stderr if stream is None else stream
        self.last_time = time.perf_counter()
        self.last_step = env_step
        self.width = 0

    def due(self) -> bool:
        """True once PROGRESS_SECONDS have passed since the last refresh."""
        return self.enabled and time.perf_counter() - self.last_time >= PROGRESS_SECONDS

    def steps_per_second(self, env_step: int) -> float:
        """Environment steps per second since the last refresh (and start a new window)."""
        now = time.perf_counter()
        rate = (env_step - self.last_step) / max(now - self.last_time, 1e-9)
        self.last_time, self.last_step = now, env_step
        return rate

    def show(self, text: str) -> None:
        if self.enabled:
            self.stream.write("\r" + text.ljust(self.width))
            self.stream.flush()
            self.width = len(text)

    def note(self, text: str) -> None:
        """A line of its own, above the status line."""
        if self.enabled:
            self.stream.write("\r" + " " * self.width + "\r" + text + "\n")
            self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.width:
            self.stream.write("\n")
            self.stream.flush()


def write_record(path: Path, record: dict[str, Any]) -> None:
    """Append one JSON object as a line of the metrics log."""
    with path.open("a") as log:
        log.write(json.dumps(record) + "\n")


def recent_means(recent: deque) -> dict[str, float | dict[str, float] | None]:
    """Means over the recent episodes, each (success, return, collision ratio, steps,
    return by term [7], the team-wide share of its cooperation term); None when there are none yet."""
    if not recent:
        return {
            "success_rate": None, "mean_return": None, "return_terms": None, "team_cooperation": None,
            "collision_ratio": None, "episode_steps": None,
        }
    success, returns, collisions, steps, terms, team = zip(*recent)
    return {
        "success_rate": float(np.mean(success)),
        "mean_return": float(np.mean(returns)),
        "return_terms": dict(zip(REWARD_TERMS, np.mean(terms, axis=0).tolist())),
        "team_cooperation": float(np.mean(team)),
        "collision_ratio": float(np.mean(collisions)),
        "episode_steps": float(np.mean(steps)),
    }


# ---------------------------------------------------------------- resume
SNAPSHOT_EVALUATOR = "terl_rt.evaluation"
"""What measured a run's snapshots (Counters.snapshot_evaluator): scores of checkpoints written
before snapshots ran through terl_rt.evaluation (None there) do not compare with today's."""


def restore_buffer(
    resume: Path, saved_config: Config, config: Config, counters: Counters, buffer: ReplayBuffer, load: bool = True
) -> tuple[int, str]:
    """Load a resumed run's replay buffer when it was saved, fits and `load` is true, else plan its refill.

    Returns the transitions the buffer must hold again before updates resume (0: none to wait
    for) and the note that says which. Without a saved buffer it is refilled to the transitions
    it held (`Counters.replay_transitions`; its capacity for older checkpoints), and for at
    least `learning_starts` environment steps: updating on a buffer a tenth as full as before
    made the policy collapse within 20 k steps. The refill's environment steps do not count
    toward the schedule (`Refill`).
    """
    learning_starts = config.data.learning_starts
    saved = resume / REPLAY_FILE
    unused = "no saved replay buffer" if load else "its saved replay buffer is not used (a refill)"
    return_changes = changed_fields(saved_config, config, RETURN_FIELDS)
    if saved.is_file() and return_changes:  # a fine-tune that stores other returns
        unused = f"its saved replay buffer was stored under other {', '.join(return_changes)}"
    elif saved.is_file() and load:
        try:
            buffer.load(saved)
        except ValueError as error:  # a fine-tune on a scenario with other evader slots
            unused = f"its saved replay buffer does not fit ({error})"
    owed = min(buffer.capacity, counters.replay_transitions or 0)  # what it held before any refill cut off
    if len(buffer) and len(buffer) >= owed:
        return 0, (
            f"resumed from {resume} at environment step {counters.env_step} with its replay buffer "
            f"({len(buffer):,} transitions)"
        )
    if len(buffer):  # a saved buffer of a refill cut off: the refill goes on
        unused = f"its saved replay buffer holds {len(buffer):,} transitions, a refill cut off"
    refill_to = min(buffer.capacity, counters.replay_transitions or buffer.capacity)
    if not counters.replay_transitions:
        held = f"its capacity, {refill_to:,} transitions (the checkpoint does not say what it held)"
    elif counters.replay_transitions > refill_to:
        held = f"its capacity, {refill_to:,} transitions (the checkpoint held {counters.replay_transitions:,})"
    else:
        held = f"the {refill_to:,} transitions it held"
    return refill_to, (
        f"resumed from {resume} at environment step {counters.env_step}; {unused}, it is refilled to {held}, "
        f"and for at least {learning_starts} environment steps, before updates resume; the refill's steps "
        "do not count toward the schedule"
    )


# ---------------------------------------------------------------- one seed's part
@dataclass(frozen=True)
class SeedRun:
    """One seed of a run: its seed, its output folder and the checkpoint it continues (None: it starts)."""

    seed: int
    out_dir: Path
    resume: Path | None = None


class SeedFailed(RuntimeError):
    """Every seed of a run stopped on a non-finite loss (each one's last checkpoint stays)."""


class SeedState:
    """One seed's part of a run: its config, folder, generator, counters, replay buffer, worlds
    and records, laid out as a one-seed run lays them out. The `Learner` holds its networks."""

    def __init__(self, run: SeedRun, config: Config, learner: Learner, index: int, load_replay: bool,
                 progress: Progress, many: bool) -> None:
        self.seed = run.seed
        self.label = f"seed {run.seed}: " if many else ""
        """How progress lines name the seed ("" while it trains alone)."""
        self.config = config.replace(seed=run.seed)
        self.out_dir = Path(run.out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.log_path = self.out_dir / METRICS_FILE
        self.rng = np.random.default_rng(run.seed)
        self.counters = Counters(snapshot_evaluator=SNAPSHOT_EVALUATOR)
        self.refill_to = 0
        """transitions a resume's buffer must hold again before updates resume (0: none owed)."""
        data, schedule = self.config.data, self.config.schedule
        note = None
        if run.resume is not None:
            saved = load_checkpoint(run.resume)
            learner.load_seed_state(index, saved.online, saved.target, saved.optimizer)
            restore_rng_states(saved.rng, self.rng, learner.generators[index])
            self.counters = saved.counters
        self.wall_before = self.counters.wall_seconds
        """seconds spent training in earlier sessions."""
        self.buffer = ReplayBuffer(data.buffer_size, buffer_evader_slots(
            training_scenarios(schedule, data.reward, self.counters.env_step)))
        if run.resume is not None:
            progress.show(f"loading the replay buffer of {run.resume}")
            note = self.restore(Path(run.resume), load_replay)
            write_record(self.log_path, {"kind": "resume", "env_step": self.counters.env_step, "note": note})
            progress.note(note)
        self.groups: list[WorldGroup] = []
        self.recent: deque = deque(maxlen=RECENT_EPISODES)
        self.losses: list[float] = []
        """losses of the updates since the last "train" record."""
        self.last_loss: float | None = None
        """loss of its last update, for the status line (None before one)."""

    def restore(self, resume: Path, load_replay: bool) -> str:
        """Load or plan the refill of the resumed buffer (`restore_buffer`); a best that no longer
        compares starts over. Returns the note that says which."""
        saved_config = read_config(resume)
        self.refill_to, note = restore_buffer(resume, saved_config, self.config, self.counters, self.buffer, load_replay)
        # A fine-tune that evaluates snapshots on other scenarios, or a run whose snapshots were
        # measured by another evaluator, starts its own best: such scores do not compare.
        evaluation_changes = changed_fields(saved_config, self.config, SNAPSHOT_FIELDS)
        if self.counters.snapshot_evaluator != SNAPSHOT_EVALUATOR:
            evaluation_changes.append("the evaluator")
            self.counters.snapshot_evaluator = SNAPSHOT_EVALUATOR
        if evaluation_changes:
            self.counters.best_score, self.counters.best_step = None, None
            note += f"; snapshots are evaluated anew ({', '.join(evaluation_changes)} changed), so the best starts over"
        return note

    def enter_stage(self, scenarios: list[Scenario], announce: bool) -> None:
        """New worlds for a new stage (episodes under way are dropped); `announce` logs it."""
        learner = self.config.learner
        num_envs = self.config.schedule.num_envs
        self.groups = [WorldGroup(scenario, num_envs, self.buffer, self.config.data, learner.gamma, self.rng) for scenario in scenarios]
        name = stage_label(scenarios)
        if name not in self.counters.stages:
            self.counters.stages.append(name)
        if announce:
            write_record(self.log_path, {"kind": "stage", "env_step": self.counters.env_step, "stage": name})

    def collect(self, actor: QNetwork, group_index: int, epsilon: float) -> None:
        """One batch step of worlds group `group_index`: act (epsilon-greedy), store, count episodes."""
        group = self.groups[group_index]
        turn = group.rollout.turn()  # restarts the worlds whose episode ended in the last step
        states = turn.observation.rows(turn.rows).as_inputs()
        step = group.rollout.step(epsilon_greedy(actor, states, epsilon, self.rng, self.config.learner.random_acting_fractions))
        # the next observation is the one before any restart
        group.transitions.add(turn.rows, states, step.actions, step.observation, step.result, self.rng)
        pursuers = group.scenario.pursuers
        group.returns += step.result.reward.sum(axis=1) / pursuers
        group.terms += step.result.reward_terms.sum(axis=1) / pursuers
        group.team += step.result.team_cooperation * step.result.acted.sum(axis=1) / pursuers
        for env, outcome in step.outcomes.items():
            self.recent.append((
                outcome.success, group.returns[env], outcome.collision_ratio, outcome.steps,
                group.terms[env].copy(), group.team[env],
            ))
            group.returns[env], group.terms[env], group.team[env] = 0.0, 0.0, 0.0
            self.counters.episodes += 1

    def snapshot(self, learner: Learner, index: int, progress: Progress) -> None:
        """Evaluate its online network, log it, keep it (RunConfig.keep_snapshots) and in best/ when it scores best."""
        run, counters, model = self.config.run, self.counters, learner.online[index]
        progress.show(f"step {counters.env_step:,}: {self.label}snapshot evaluation ({run.snapshot_episodes} episodes a scenario)")
        record, better = take_snapshot(model, self.groups[0].scenario, run, counters.best_score)
        write_record(self.log_path, {**record, "env_step": counters.env_step})
        if run.keep_snapshots:
            save_snapshot(snapshot_folder(self.out_dir, counters.env_step), self.config, model, counters)
        if better:
            counters.best_score, counters.best_step = record["score"], counters.env_step
            counters.replay_transitions = len(self.buffer)
            self.checkpoint(learner, index, self.out_dir / BEST_FOLDER)
            progress.note(f"{self.label}snapshot at {counters.env_step}: score {record['score']:.3f}, "
                          f"the best so far (kept in {BEST_FOLDER}/)")

    def log_train(self, epsilon: float, learning_rate: float, stage_name: str, session_steps: int,
                  session_seconds: float) -> None:
        """The "train" record of metrics.jsonl (its losses since the last are cleared)."""
        counters = self.counters
        write_record(self.log_path, {
            "kind": "train",
            "env_step": counters.env_step,
            "episodes": counters.episodes,
            "updates": counters.updates,
            "stage": stage_name,
            "epsilon": epsilon,
            "learning_rate": learning_rate,
            "loss": float(np.mean(self.losses)) if self.losses else None,
            **recent_means(self.recent),
            "steps_per_second": session_steps / max(session_seconds, 1e-9),
            "wall_seconds": counters.wall_seconds,
        })
        self.losses.clear()

    def checkpoint(self, learner: Learner, index: int, folder: Path | None = None, stopping: bool = False) -> None:
        """A whole checkpoint into `folder` (the run's own by default), state.json last. Into its
        own folder the replay buffer goes first: with every checkpoint (DataConfig.save_replay),
        else with the one a stop writes alone (`stopping`: a resume on this machine goes on with it
        rather than refill), a file the next checkpoint removes, as it would be stale."""
        if folder is None:
            self.counters.replay_transitions = max(len(self.buffer), self.refill_to)  # a refill cut off still owes what it held
            if self.config.data.save_replay or stopping:
                self.buffer.save(self.out_dir / REPLAY_FILE)
            else:
                (self.out_dir / REPLAY_FILE).unlink(missing_ok=True)
        online, target, optimizer = learner.seed_state(index)
        state = TrainingState(online, target, optimizer, self.counters, rng_states(self.rng, learner.generators[index]))
        save_checkpoint(folder or self.out_dir, self.config, state)
