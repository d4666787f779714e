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

Transitions: each pursuer's step is stored with the reward the learner is taught
(terl_rt.sim.reward.taught_reward under `DataConfig`: shaping, collision value, scale) and,
when `DataConfig.store_pursuers` is set, only a random subset of a world step's pursuers
enter the buffer. A pursuer's transition is terminal when it collides, and when its episode
terminates if `DataConfig.success_ends_transitions`; when it is truncated, if
`DataConfig.truncation_ends`. Acting takes the mean of the quantiles at the contract's fixed
fractions, or at random ones (`LearnerConfig.random_acting_fractions`).

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

`train_seeds` is the loop, read top to bottom; the helpers before it do one thing each.
training/lab/throughput.py times the loop's two halves (rollout, update) apart.
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
import torch

from terl_rt.evaluation.evaluate import evaluate_policy
from terl_rt.sim.actions import NUM_PURSUER_ACTIONS
from terl_rt.sim.observation import Observation
from terl_rt.sim.reward import REWARD_TERMS, taught_reward
from terl_rt.sim.rollout import Rollout
from terl_rt.sim.scenario import Scenario, curriculum_stage
from terl_rt.sim.world import StepResult, World
from training.buffer import ReplayBuffer, pad_evader_slots, trim_padding
from training.checkpoint import (
    Counters, TrainingState, load_checkpoint, read_config, restore_rng_states, rng_states, save_checkpoint,
    save_snapshot,
)
from training.config import (
    RETURN_FIELDS, SNAPSHOT_FIELDS, Config, DataConfig, LearnerConfig, RunConfig, ScheduleConfig, changed_fields,
)
from training.learner import Learner
from training.losses import linear_schedule
from training.networks import QNetwork
from training.networks.encoders import NUM_FIXED_FRACTIONS
from training.stops import StopRequests, TrainingStopped
from training.torch_policy import TorchPolicy, as_tensors, network_device

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


def crossings(before: int, after: int, every: int) -> int:
    """How many multiples of `every` lie in (before, after]: events due in a batch step."""
    return after // every - before // every


# ---------------------------------------------------------------- acting
def greedy_actions(model: QNetwork, states: dict[str, np.ndarray], fractions: np.ndarray | None = None) -> np.ndarray:
    """argmax of the eval-mode Q-values of the states with their empty slots trimmed
    (`trim_padding`): [R] int64. Q-values are the mean of the quantiles at the fixed fractions,
    as the exported policy's, or at `fractions` [R, K] in [0, 1), a row's own."""
    if len(states["ego"]) == 0:
        return np.zeros(0, np.int64)
    model.eval()
    inputs = as_tensors(trim_padding(states), network_device(model))
    taus = None if fractions is None else torch.from_numpy(fractions).to(inputs[0].device)
    with torch.inference_mode():
        return model.q_values(*inputs, taus).argmax(dim=1).cpu().numpy()


def epsilon_greedy(
    model: QNetwork, states: dict[str, np.ndarray], epsilon: float, rng: np.random.Generator,
    random_fractions: bool = False,
) -> np.ndarray:
    """Action indices [R] for the rows' states [R, ...]: greedy in one batched forward,
    each row replaced by a uniformly random action with probability `epsilon`. With
    `random_fractions` each row's Q-values are its mean at NUM_FIXED_FRACTIONS fractions drawn
    from `rng` (LearnerConfig.random_acting_fractions), not at the fixed ones."""
    drawn = rng.random((len(states["ego"]), NUM_FIXED_FRACTIONS), dtype=np.float32) if random_fractions else None
    return explore(greedy_actions(model, states, drawn), epsilon, rng)


def explore(chosen: np.ndarray, epsilon: float, rng: np.random.Generator) -> np.ndarray:
    """The action indices `chosen` [R], each replaced in place by a uniformly random action
    with probability `epsilon`; returns them."""
    random = rng.random(len(chosen)) < epsilon
    chosen[random] = rng.integers(0, NUM_PURSUER_ACTIONS, int(random.sum()))
    return chosen


class TransitionStore:
    """What goes from a batch step into the replay buffer: every acting pursuer row (b * N + i
    of the B worlds) with the reward it is taught, and the optional per-step subsample."""

    def __init__(self, buffer: ReplayBuffer, data: DataConfig, gamma: float, num_rows: int) -> None:
        self.buffer = buffer
        self.data = data
        self.gamma = gamma
        self.potential = np.zeros(num_rows)
        """[rows] Phi of the state each row's last step ended in (DataConfig.potential_shaping; 0 before an episode)."""

    def add(
        self,
        rows: np.ndarray,
        states: dict[str, np.ndarray],
        actions: np.ndarray,
        next_observation: Observation,
        result: StepResult,
        rng: np.random.Generator,
    ) -> int:
        """Add the step of every pursuer that acted (rows [R] b * N + n and their states [R, ...],
        actions [B, N]); returns the transitions stored. Observations with fewer evader slots
        than the buffer's are padded to them (`pad_evader_slots`)."""
        num_pursuers = result.collided.shape[1]
        slots = self.buffer.shapes["evaders"][0]
        rewards, terminal, _ = taught_step(result, rows, self.potential, self.data, self.gamma)
        keep = np.arange(len(rows))
        if self.data.store_pursuers:
            # at most store_pursuers transitions per world of this step, drawn at random
            keep = subsample_per_group(rows // num_pursuers, self.data.store_pursuers, rng)
        states = pad_evader_slots({key: value[keep] for key, value in states.items()}, slots)
        next_states = pad_evader_slots(next_observation.rows(rows[keep]).as_inputs(), slots)
        self.buffer.add(
            states, actions.ravel()[rows[keep]], rewards[keep].astype(np.float32), next_states, terminal[keep],
            np.full(len(keep), self.gamma, np.float32),
        )
        return len(keep)


def taught_step(
    result: StepResult, rows: np.ndarray, potential: np.ndarray, data: DataConfig, gamma: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the learner is taught about one step of the pursuer rows [R] (b * N + n) that acted.

    Returns their rewards [R] (terl_rt.sim.reward.taught_reward of the terms the world paid,
    under `data`'s shaping, collision value and scale), whether each transition is terminal [R]
    (the pursuer collided, or its episode terminated (all evaders encircled, or too few
    pursuers left) when `data.success_ends_transitions`, or truncated when `data.truncation_ends`;
    other transitions are bootstrapped) and whether each row's episode stops here [R]
    (terminated or truncated). potential [B * N]: Phi of the state each row's last step ended
    in, updated in place (0 where the episode stops).
    """
    ended = (result.terminated | result.truncated)[:, None]
    ends = (result.terminated & data.success_ends_transitions) | (result.truncated & data.truncation_ends)  # [B]
    terminal = result.collided | ends[:, None]
    stops = np.broadcast_to(ended, terminal.shape).ravel()[rows]
    terminal = terminal.ravel()[rows]
    terms = result.reward_terms.reshape(-1, len(REWARD_TERMS))[rows]
    rewards, next_potential = taught_reward(
        terms, result.collided.ravel()[rows], terminal, potential[rows], gamma,
        data.reward_scale, data.potential_shaping, data.collision_value,
    )
    potential[rows] = np.where(terminal | stops, 0.0, next_potential)
    return rewards, terminal, stops


class WorldGroup:
    """B worlds of one scenario under training: their rollout, the transition store of their
    pursuer rows, and the sums of the episodes under way."""

    def __init__(
        self, scenario: Scenario, num_envs: int, buffer: ReplayBuffer, data: DataConfig, gamma: float,
        rng: np.random.Generator,
    ) -> None:
        self.scenario = scenario
        self.rollout = Rollout(World(scenario, num_envs, seed=int(rng.integers(2**31))))
        self.transitions = TransitionStore(buffer, data, gamma, num_envs * scenario.pursuers)
        self.returns = np.zeros(num_envs)
        """[B] per-pursuer return of each world's episode so far (summed rewards / N)."""
        self.terms = np.zeros((num_envs, len(REWARD_TERMS)))
        """[B, terms] the same split by reward term."""
        self.team = np.zeros(num_envs)
        """[B] the team-wide share of the cooperation term in it (StepResult.team_cooperation)."""


def subsample_per_group(groups: np.ndarray, limit: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of at most `limit` items of each group (groups [K] ints), drawn at random, sorted."""
    order = rng.permutation(len(groups))
    shuffled = groups[order]
    by_group = np.argsort(shuffled, kind="stable")
    sorted_groups = shuffled[by_group]
    first = np.searchsorted(sorted_groups, sorted_groups, side="left")
    rank = np.arange(len(groups)) - first
    return np.sort(order[by_group[rank < limit]])


# ---------------------------------------------------------------- learning
def learning_rate_at(learner: LearnerConfig, total_steps: int, env_step: int) -> float:
    """Adam's step size at `env_step`: `learning_rate`, or with `final_learning_rate` its linear
    fall from `decay_start` to `total_steps`."""
    if not learner.final_learning_rate:
        return learner.learning_rate
    return linear_schedule(
        learner.learning_rate, learner.final_learning_rate,
        total_steps - learner.decay_start, env_step - learner.decay_start,
    )


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
