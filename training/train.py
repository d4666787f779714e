"""Training of a pursuer Q-network: IQN (or DQN) with a shared network for every pursuer.

Centralised training, decentralised execution (policy.md section 2): B worlds are
stepped together; one batched forward of the online network (or of its copy refreshed every
`LearnerConfig.actor_update_frequency` steps) chooses the action of
every active pursuer of every world (epsilon-greedy per pursuer), and every active
pursuer's transition goes into one replay buffer. With `ScheduleConfig.mixed_scenarios` there is a
group of B worlds per scenario (`WorldGroup`) and the batch steps go to the groups in turn,
all into the one buffer (rows padded to the most evader slots).

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
terminates if `DataConfig.success_ends_transitions`; truncation is bootstrapped.

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

`train` is the loop, read top to bottom; the helpers before it do one thing each.
training/throughput.py times the loop's two halves (rollout, update) apart.
"""

from __future__ import annotations

import copy
import json
import sys
import time
from collections import deque
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import torch

from terl_rt.evaluation.episodes import evaluate_policy
from terl_rt.sim.actions import NUM_PURSUER_ACTIONS
from terl_rt.sim.observation import Observation
from terl_rt.sim.reward import REWARD_TERMS, taught_reward
from terl_rt.sim.rollout import Rollout
from terl_rt.sim.scenario import Scenario, curriculum_stage
from terl_rt.sim.world import StepResult, World
from training.buffer import ReplayBatch, ReplayBuffer, pad_evader_slots, trim_padding
from training.checkpoint import (
    Counters, load_checkpoint, network_from_config, read_config, save_checkpoint, save_snapshot, seed_generators,
)
from training.config import (
    RETURN_FIELDS, SNAPSHOT_FIELDS, Config, DataConfig, LearnerConfig, NetworkConfig, RunConfig,
    ScheduleConfig, changed_fields,
)
from training.losses import huber, linear_schedule, quantile_huber_loss, quantile_td_target, td_target
from training.networks import QNetwork
from training.stops import StopRequests, TrainingStopped
from training.torch_policy import TorchPolicy, as_tensors, network_device

REPLAY_FILE = "replay.npz"
"""The saved replay buffer, beside the checkpoint files (DataConfig.save_replay)."""
BEST_FOLDER = "best"
"""Subfolder of the run holding the best snapshot so far, as a checkpoint."""
SNAPSHOTS_FOLDER = "snapshots"
"""Subfolder of the run holding every snapshot's online network by environment step (RunConfig.keep_snapshots)."""
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
    `mixed_scenarios`, with the reward variant `reward` and the training episode limit."""
    if schedule.curriculum:
        scenarios = [curriculum_stage(env_step, schedule.curriculum_steps or schedule.total_steps)]
    else:
        scenarios = [Scenario.preset(name) for name in (schedule.scenario, *schedule.mixed_scenarios)]
    return [scenario.replace(reward=reward, max_steps=schedule.train_max_steps) for scenario in scenarios]


def stage_label(scenarios: list[Scenario]) -> str:
    """What a run trains on at once, as logged: the scenarios' names joined by '+'."""
    return "+".join(scenario.name for scenario in scenarios)


def buffer_evader_slots(scenarios: list[Scenario]) -> int:
    """Evader slots of the replay buffer rows: the most of the scenarios (the others are padded)."""
    return max(scenario.evader_slots for scenario in scenarios)


def crossings(before: int, after: int, every: int) -> int:
    """How many multiples of `every` lie in (before, after]: events due in a batch step."""
    return after // every - before // every


# ---------------------------------------------------------------- acting
def greedy_actions(model: QNetwork, states: dict[str, np.ndarray]) -> np.ndarray:
    """argmax of the eval-mode Q-values (fixed fractions, as the exported policy) of the states
    with their empty slots trimmed (`trim_padding`): [R] int64."""
    if len(states["ego"]) == 0:
        return np.zeros(0, np.int64)
    model.eval()
    with torch.inference_mode():
        return model.q_values(*as_tensors(trim_padding(states), network_device(model))).argmax(dim=1).cpu().numpy()


def epsilon_greedy(
    model: QNetwork, states: dict[str, np.ndarray], epsilon: float, rng: np.random.Generator
) -> np.ndarray:
    """Action indices [R] for the rows' states [R, ...]: greedy in one batched forward,
    each row replaced by a uniformly random action with probability `epsilon`."""
    return explore(greedy_actions(model, states), epsilon, rng)


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
    pursuers left) when `data.success_ends_transitions`; truncated episodes, and terminated
    ones otherwise, are bootstrapped) and whether each row's episode stops here [R]
    (terminated or truncated). potential [B * N]: Phi of the state each row's last step ended
    in, updated in place (0 where the episode stops).
    """
    ended = (result.terminated | result.truncated)[:, None]
    terminal = result.collided | (result.terminated[:, None] if data.success_ends_transitions else False)
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
def td_loss(model: QNetwork, target: QNetwork, batch: ReplayBatch, learner: LearnerConfig, trim: bool = True) -> torch.Tensor:
    """Quantile Huber loss (IQN heads) or Huber TD loss (`dqn`) of a sampled batch, a scalar.

    The online network runs as it is (train mode: dropout on); the target network,
    in eval mode, gives R + gamma^k * (1 - done) * Z_target(s', a*) with a* its own
    argmax of the mean, or with `learner.double_dqn` the online network's argmax.
    `trim` cuts the slots empty in every row of the batch first (`trim_padding`: the same
    loss to float round-off, in less time); `learner.bf16` runs the networks under bfloat16
    autocast, their heads' output layers and the loss in float32.
    """
    device = network_device(model)
    observations, next_observations = batch.observations, batch.next_observations
    if trim:
        observations, next_observations = trim_padding(observations), trim_padding(next_observations)
    states, next_states = as_tensors(observations, device), as_tensors(next_observations, device)
    actions = torch.from_numpy(batch.actions).to(device)
    rewards, dones = torch.from_numpy(batch.rewards).to(device), torch.from_numpy(batch.dones).to(device)
    discounts = torch.from_numpy(batch.discounts).to(device)
    rows = len(actions)
    with torch.autocast(device.type, dtype=torch.bfloat16, enabled=learner.bf16):
        if model.distributional:
            taus = torch.rand(rows, learner.num_quantiles, device=device)
            quantiles = model(*states, taus).quantiles  # [R, N, A]
            index = actions[:, None, None].expand(-1, learner.num_quantiles, 1)
            taken = quantiles.gather(2, index).squeeze(2)  # [R, N]
            with torch.no_grad():
                next_taus = torch.rand(rows, learner.num_target_quantiles, device=device)
                next_quantiles = target(*next_states, next_taus).quantiles
                best = model(*next_states, next_taus).quantiles.mean(dim=1).argmax(dim=1) if learner.double_dqn else None
                targets = quantile_td_target(rewards, dones, next_quantiles, discounts, best)
            return quantile_huber_loss(taken, taus, targets)
        q_values = model(*states).quantiles[:, 0]  # [R, A]
        taken = q_values.gather(1, actions[:, None]).squeeze(1)
        with torch.no_grad():
            best = model(*next_states).quantiles[:, 0].argmax(dim=1) if learner.double_dqn else None
            targets = td_target(rewards, dones, target(*next_states).quantiles[:, 0], discounts, best)
        return huber(taken - targets).mean()


def acting_network(model: QNetwork, actor_update_frequency: int) -> QNetwork:
    """The network that acts in training: `model` itself, or with `actor_update_frequency`
    (LearnerConfig) a copy of it (eval mode, no gradients) that the loop refreshes every so many steps."""
    if not actor_update_frequency:
        return model
    return copy.deepcopy(model).eval().requires_grad_(False)  # draws no random numbers


def learning_rate_at(learner: LearnerConfig, total_steps: int, env_step: int) -> float:
    """Adam's step size at `env_step`: `learning_rate`, or with `final_learning_rate` its linear
    fall from `decay_start` to `total_steps`."""
    if not learner.final_learning_rate:
        return learner.learning_rate
    return linear_schedule(
        learner.learning_rate, learner.final_learning_rate,
        total_steps - learner.decay_start, env_step - learner.decay_start,
    )


def build_learner(network: NetworkConfig, learner: LearnerConfig) -> tuple[QNetwork, QNetwork, torch.optim.Optimizer]:
    """A fresh online network, its frozen eval-mode target copy and Adam on the online weights."""
    model = network_from_config(network).to(learner.device)
    target = network_from_config(network).to(learner.device)
    target.load_state_dict(model.state_dict())
    target.eval().requires_grad_(False)
    return model, target, torch.optim.Adam(model.parameters(), lr=learner.learning_rate)


def learn(
    model: QNetwork,
    target: QNetwork,
    optimizer: torch.optim.Optimizer,
    batch: ReplayBatch,
    learner: LearnerConfig,
    trim: bool = True,
) -> float:
    """One Adam step on `td_loss` (its padding trimmed unless `trim` is false) with the gradient
    norm clipped; returns the loss."""
    model.train()
    loss = td_loss(model, target, batch, learner, trim)
    optimizer.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(model.parameters(), learner.max_grad_norm)
    optimizer.step()
    return loss.item()


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
    """Evaluate the online network on the current stage `scenario` and `run.snapshot_preset`;
    returns the "snapshot" record (without env_step) and whether it beats `best`."""
    evaluations = [greedy_evaluation(model, scenario, run), greedy_evaluation(model, Scenario.preset(run.snapshot_preset), run)]
    score = snapshot_score(evaluations, run)
    better = best is None or score > best
    return {"kind": "snapshot", "score": score, "best": better, "evaluations": evaluations}, better


# ---------------------------------------------------------------- display and log
class Progress:
    """One status line on a text stream, rewritten in place with a carriage return."""

    def __init__(self, enabled: bool, env_step: int = 0, stream: TextIO = sys.stderr) -> None:
        self.enabled = enabled
        self.stream = stream
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
    toward the schedule (`train`).
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


# ---------------------------------------------------------------- the loop
def train(
    config: Config,
    out_dir: str | Path,
    resume: str | Path | None = None,
    show_progress: bool = True,
    load_replay: bool = True,
) -> Counters:
    """Train the config's network for its schedule's `total_steps` environment steps; return the
    final counters.

    Writes metrics.jsonl, the checkpoint files (see training.checkpoint), the replay
    buffer (replay.npz, `DataConfig.save_replay`) and the best snapshot (best/,
    `RunConfig.snapshot_frequency`) into `out_dir`. With `resume`, weights, optimizer,
    counters, RNG states and, when it was saved there, the replay buffer come from that
    checkpoint (`restore_buffer`; `load_replay` false refills it instead). SIGINT (Ctrl-C) or
    SIGTERM ends the batch step, writes a whole checkpoint and raises TrainingStopped. The
    caller sets torch's thread count.
    """
    network, learner, data, schedule, run = config.network, config.learner, config.data, config.schedule, config.run
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    log_path = out_dir / METRICS_FILE

    # --- seeding
    rng = np.random.default_rng()
    seed_generators(run.seed, rng)

    # --- networks, optimiser, counters, replay buffer
    model, target, optimizer = build_learner(network, learner)
    counters = Counters(snapshot_evaluator=SNAPSHOT_EVALUATOR)
    if resume is not None:
        resume = Path(resume)
        counters = load_checkpoint(resume, model, target, optimizer, rng)
        saved_config = read_config(resume)
    actor = acting_network(model, learner.actor_update_frequency)
    progress = Progress(show_progress, counters.env_step)
    scenarios = training_scenarios(schedule, data.reward, counters.env_step)
    buffer = ReplayBuffer(data.buffer_size, buffer_evader_slots(scenarios))
    refill_to = 0  # transitions a resume's buffer must hold again before updates resume
    if resume is not None:
        progress.show(f"loading the replay buffer of {resume}")
        refill_to, note = restore_buffer(resume, saved_config, config, counters, buffer, load_replay)
        # A fine-tune that evaluates snapshots on other scenarios, or a run whose snapshots were
        # measured by another evaluator, starts its own best: such scores do not compare.
        evaluation_changes = changed_fields(saved_config, config, SNAPSHOT_FIELDS)
        if counters.snapshot_evaluator != SNAPSHOT_EVALUATOR:
            evaluation_changes.append("the evaluator")
            counters.snapshot_evaluator = SNAPSHOT_EVALUATOR
        if evaluation_changes:
            counters.best_score, counters.best_step = None, None
            note += f"; snapshots are evaluated anew ({', '.join(evaluation_changes)} changed), so the best starts over"
        write_record(log_path, {"kind": "resume", "env_step": counters.env_step, "note": note})
        progress.note(note)

    # --- environments: a group of B worlds per scenario, stepped in turn
    num_envs = schedule.num_envs
    groups = [WorldGroup(scenario, num_envs, buffer, data, learner.gamma, rng) for scenario in scenarios]
    stage_name = stage_label(scenarios)
    if stage_name not in counters.stages:
        counters.stages.append(stage_name)
    recent: deque = deque(maxlen=RECENT_EPISODES)
    losses: list[float] = []
    last_loss: float | None = None
    session_start, session_step = time.perf_counter(), counters.env_step
    wall_before = counters.wall_seconds
    refill_steps = 0  # environment steps of the refill: the schedule (stage, epsilon, step size) waits for them

    with StopRequests() as stops:
        while counters.env_step < schedule.total_steps:
            # --- curriculum: a new stage gets new worlds; episodes under way are dropped
            stage = training_scenarios(schedule, data.reward, counters.env_step)
            if stage_label(stage) != stage_name:
                groups = [WorldGroup(scenario, num_envs, buffer, data, learner.gamma, rng) for scenario in stage]
                stage_name = stage_label(stage)
                if stage_name not in counters.stages:
                    counters.stages.append(stage_name)
                write_record(log_path, {"kind": "stage", "env_step": counters.env_step, "stage": stage_name})
                progress.note(f"environment step {counters.env_step}: stage {stage_name}")
            group = groups[(counters.env_step + refill_steps) // num_envs % len(groups)]

            # --- collect: one batched forward for every active pursuer, epsilon-greedy each
            epsilon = linear_schedule(
                schedule.start_e, schedule.end_e, schedule.exploration_fraction * schedule.total_steps, counters.env_step
            )
            learning_rate = learning_rate_at(learner, schedule.total_steps, counters.env_step)
            for param_group in optimizer.param_groups:  # the config rules, not the rate a resumed optimizer saved
                param_group["lr"] = learning_rate
            turn = group.rollout.turn()  # restarts the worlds whose episode ended in the last step
            states = turn.observation.rows(turn.rows).as_inputs()
            step = group.rollout.step(epsilon_greedy(actor, states, epsilon, rng))

            # --- store (the next observation is the one before any restart)
            group.transitions.add(turn.rows, states, step.actions, step.observation, step.result, rng)

            # --- episode bookkeeping
            group.returns += step.result.reward.sum(axis=1) / group.scenario.pursuers
            group.terms += step.result.reward_terms.sum(axis=1) / group.scenario.pursuers
            group.team += step.result.team_cooperation * step.result.acted.sum(axis=1) / group.scenario.pursuers
            for env, outcome in step.outcomes.items():
                recent.append((
                    outcome.success, group.returns[env], outcome.collision_ratio, outcome.steps,
                    group.terms[env].copy(), group.team[env],
                ))
                group.returns[env], group.terms[env], group.team[env] = 0.0, 0.0, 0.0
                counters.episodes += 1
            previous_step = counters.env_step
            if refill_to:  # a resume refills its buffer at the step it stopped, as if it had never stopped
                refill_steps += num_envs
                if len(buffer) >= refill_to and refill_steps >= data.learning_starts:
                    refill_to = 0
                    progress.note(f"environment step {counters.env_step}: refilled in {refill_steps:,} steps, updates resume")
            else:
                counters.env_step += num_envs

            # --- learn: the updates due in this batch step, then the target copy when due
            if not refill_to and counters.env_step >= data.learning_starts and len(buffer) >= learner.batch_size:
                # Updates for the environment steps after learning_starts: (T - learning_starts) / 4 in all.
                due = crossings(max(previous_step, data.learning_starts), counters.env_step, learner.train_frequency)
                for _ in range(due):
                    batch = buffer.sample(learner.batch_size, rng)
                    last_loss = learn(model, target, optimizer, batch, learner)
                    losses.append(last_loss)
                    counters.updates += 1
                if crossings(previous_step, counters.env_step, learner.target_network_frequency):
                    target.load_state_dict(model.state_dict())
            if actor is not model and crossings(previous_step, counters.env_step, learner.actor_update_frequency):
                actor.load_state_dict(model.state_dict())

            # --- evaluate, snapshot and log
            finished = counters.env_step >= schedule.total_steps
            counters.wall_seconds = wall_before + time.perf_counter() - session_start
            if run.snapshot_frequency and (
                crossings(previous_step, counters.env_step, run.snapshot_frequency) or finished
            ):
                progress.show(f"step {counters.env_step:,}: snapshot evaluation ({run.snapshot_episodes} episodes a scenario)")
                record, better = take_snapshot(model, groups[0].scenario, run, counters.best_score)
                write_record(log_path, {**record, "env_step": counters.env_step})
                if run.keep_snapshots:
                    save_snapshot(out_dir / SNAPSHOTS_FOLDER / str(counters.env_step), config, model, counters)
                if better:
                    counters.best_score, counters.best_step = record["score"], counters.env_step
                    counters.replay_transitions = len(buffer)
                    save_checkpoint(out_dir / BEST_FOLDER, config, model, target, optimizer, counters, rng)
                    progress.note(f"snapshot at {counters.env_step}: score {record['score']:.3f}, the best so far (kept in {BEST_FOLDER}/)")
            if finished or crossings(previous_step, counters.env_step, run.log_frequency):
                session_seconds = time.perf_counter() - session_start
                record = {
                    "kind": "train",
                    "env_step": counters.env_step,
                    "episodes": counters.episodes,
                    "updates": counters.updates,
                    "stage": stage_name,
                    "epsilon": epsilon,
                    "learning_rate": learning_rate,
                    "loss": float(np.mean(losses)) if losses else None,
                    **recent_means(recent),
                    "steps_per_second": (counters.env_step - session_step) / max(session_seconds, 1e-9),
                    "wall_seconds": counters.wall_seconds,
                }
                write_record(log_path, record)
                losses.clear()
            if progress.due() and refill_to:
                progress.steps_per_second(counters.env_step)  # starts the next refresh window
                progress.show(f"step {counters.env_step:,}: refilling the replay buffer, {len(buffer):,}/{refill_to:,} transitions")
            elif progress.due() or finished:
                means = recent_means(recent)
                success = "-" if means["success_rate"] is None else f"{means['success_rate']:.2f}"
                loss_text = "-" if last_loss is None else f"{last_loss:.3g}"
                progress.show(
                    f"step {counters.env_step:,}/{schedule.total_steps:,} | "
                    f"{progress.steps_per_second(counters.env_step):,.0f} steps/s | "
                    f"episodes {counters.episodes} | success {success} | loss {loss_text} | "
                    f"eps {epsilon:.3f} | updates {counters.updates} | {stage_name}"
                )

            # --- checkpoint (the replay buffer first: state.json, written last, marks a whole checkpoint)
            stopping = stops.received is not None
            if finished or stopping or crossings(previous_step, counters.env_step, run.checkpoint_frequency):
                counters.replay_transitions = max(len(buffer), refill_to)  # a refill cut off still owes what it held
                if data.save_replay:
                    progress.show(f"step {counters.env_step:,}: saving the replay buffer ({len(buffer):,} transitions)")
                    buffer.save(out_dir / REPLAY_FILE)
                save_checkpoint(out_dir, config, model, target, optimizer, counters, rng)
            if stopping:
                progress.close()
                raise TrainingStopped(stops.received, counters.env_step, out_dir)

    progress.close()
    return counters
