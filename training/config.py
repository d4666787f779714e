"""The training configuration, nested by concern: network, learner, data (and the reward
transform), schedule, run. Each part is a small frozen dataclass with one documented field
per setting; each helper of the loop takes only the part it needs.

The defaults are the settings of the shipped TERL's first segment (`recipes/terl.toml`, run A
of docs/training.md), which is also the recipe of every policy of the comparison: a recipe
names only the fields it changes. Step counts are environment steps: one batch step of
`num_envs` vectorised environments is `num_envs` environment steps, the way the paper counts
the steps of its single environment. Each environment step stores one transition per active
pursuer.

A config is written as a JSON object of the five parts (`to_dict`); the flat objects that runs
wrote before the split (every field at the top level) still read (`from_dict`), and so do the
knobs that were retired (`RETIRED_FIELDS`), at the value that kept them out of the way.
"""

from __future__ import annotations

import dataclasses
import json
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from terl_rt.policy import models
from terl_rt.sim.evader import DEFAULT_EVADER, UnknownEvader, evader_kind
from terl_rt.sim.reward import REWARD_VARIANTS
from terl_rt.sim.scenario import CURRICULUM_STARTS, PRESETS

CURRICULUM_STAGES = tuple(name for _, name in CURRICULUM_STARTS)
"""The curriculum's stage presets, in order (world.md section 11)."""


class ConfigError(ValueError):
    """A configuration that is malformed; the message names the field (or file)."""


MODELS: tuple[str, ...] = tuple(models.MODELS)
"""The network bodies `NetworkConfig.model` may name: the runtime's registry
(terl_rt.policy.models), read without importing torch; training.networks maps each to its class."""


@dataclass(frozen=True)
class NetworkConfig:
    """The network: which body and its sizes (policy.md section 1)."""

    model: str = "terl"
    """network registry name, one of MODELS."""
    hidden: int = 64
    """H: token and feature width (the paper's 256; 64 trains about 10x faster on a CPU core)."""
    layers: int = 2
    """L: transformer layers (the paper's 4; 0 for bodies without a transformer)."""
    heads: int = 4
    """h: attention heads, must divide H (the paper's 8; 0 for bodies without a transformer)."""
    dropout: float = 0.0
    """dropout probability inside the transformer layers while learning (the paper's 0.1 costs
    half an update on a CPU: docs/training.md)."""


@dataclass(frozen=True)
class LearnerConfig:
    """How the network learns from sampled transitions (policy.md section 2)."""

    gamma: float = 0.99
    """discount factor per decision step (0.5 s), in [0, 1]."""
    learning_rate: float = 2.5e-4
    """Adam step size (the first, when final_learning_rate is set)."""
    final_learning_rate: float = 0.0
    """0: the step size stays learning_rate. > 0: it falls linearly from learning_rate at
    environment step decay_start to final_learning_rate at the schedule's total_steps."""
    decay_start: int = 0
    """environment step at which the final_learning_rate decay begins."""
    batch_size: int = 128
    """transitions (pursuer rows) per gradient update."""
    max_grad_norm: float = 0.5
    """global gradient-norm clip."""
    train_frequency: int = 4
    """environment steps per gradient update: a batch step of B envs runs the updates whose
    multiples of train_frequency it crossed (B/4 on average)."""
    target_network_frequency: int = 10_000
    """environment steps between hard copies of the online network to the target."""
    actor_update_frequency: int = 0
    """0: the online network acts, changing with every update (the published setting). K > 0: a
    copy of it acts, refreshed every K environment steps (and at a resume), so the data come
    from one fixed network K steps at a time (docs/training-mattered.md, 9). A resume
    continues bit for bit when the run's checkpoint_frequency is a multiple of K."""
    num_quantiles: int = 8
    """N: fractions sampled for the online quantiles of each transition (unused by dqn)."""
    num_target_quantiles: int = 8
    """N': fractions sampled for the target quantiles (unused by dqn)."""
    double_dqn: bool = False
    """double-DQN targets: the online network picks the next action, the target network values
    it (the published trainer takes the target network's own max)."""
    max_per_fraction: bool = False
    """IQN targets: false takes the target network's action of the greatest mean over the N'
    fractions, for every fraction; true the greatest value at each fraction on its own, as the
    published trainer does (an action a fraction; not with double_dqn)."""
    target_dropout: bool = False
    """false: the target network computes TD targets in eval mode (no dropout); true: with
    its dropout on, as the published trainer leaves it (NetworkConfig.dropout > 0 only)."""
    random_acting_fractions: bool = False
    """false: the acting network's Q-values are the mean of its quantiles at the ONNX
    contract's 32 fixed fractions (k + 0.5) / 32; true: at 32 random ones drawn afresh for
    every row of every step (from the run's seeded generator), as the published trainer acts.
    Snapshots and exported policies always use the fixed ones."""
    device: str = "cpu"
    """torch device of the networks and updates ("cpu", "cuda[:K]"); rollouts stay on the CPU."""
    bf16: bool = False
    """run the network body of updates under bfloat16 autocast (the heads' output layers and the
    loss stay float32); acting stays float32. 1.11x the updates/s of float32 at H = 64 on one
    core of these CPUs (`python -m training bench`)."""


@dataclass(frozen=True)
class DataConfig:
    """What enters the replay buffer: which transitions, and the reward they are taught
    (terl_rt.sim.reward.taught_reward)."""

    reward: str = "paper"
    """reward variant of the training worlds (world.md section 9): "paper" or "published"."""
    reward_scale: float = 1.0
    """c: every taught reward, the collision value included, times c (returns in units of 1 / c).
    The greedy policy is the same for any c > 0."""
    potential_shaping: float = 0.0
    """k: 0 teaches the reward as the variant pays it; k > 0 pays its guidance term and the
    positive part of its cooperation term as a potential difference (taught_reward)."""
    collision_value: float = 0.0
    """V_c <= 0: the value a collided pursuer's terminal transition ends on, in return units
    (0: nothing, the published setting)."""
    success_ends_transitions: bool = True
    """true: an episode that terminates (the last evader encircled, or fewer than 3 pursuers
    left) ends its surviving pursuers' transitions at 0; false: they are bootstrapped, as the
    published trainer does. Collisions always end a pursuer's transition."""
    truncation_ends: bool = False
    """false: a training episode cut at train_max_steps bootstraps its pursuers' last
    transitions; true: ends them at 0, as the published trainer does."""
    buffer_size: int = 500_000
    """replay capacity in pursuer transitions (about 1 KB each)."""
    learning_starts: int = 3000
    """environment steps collected before the first update (again after a resume)."""
    store_pursuers: int = 0
    """pursuer transitions of each world step that enter the buffer, a random subset of the
    pursuers that acted (0: all of them, the published setting)."""
    save_replay: bool = True
    """save the replay buffer with every checkpoint (replay.npz): a resume on the same machine
    continues with it; without it the buffer is refilled first. False saves it only with the
    checkpoint a stop writes (a signal, a grid's time limit), which the next checkpoint removes:
    a run cut into sessions on one machine then refills only where that file is gone."""


@dataclass(frozen=True)
class ScheduleConfig:
    """What is trained on, for how long, and how exploration falls."""

    total_steps: int = 200_000
    """length of training in environment steps (num_envs per batch step)."""
    num_envs: int = 8
    """B: environments stepped together; one batched forward acts for all their pursuers."""
    curriculum: bool = True
    """walk the five curriculum stages (world.md section 11) at their published shares
    (2 : 2 : 1 : 1 : 1), scaled to curriculum_steps."""
    curriculum_steps: int = 0
    """environment steps the curriculum's stage boundaries are scaled to (0: total_steps); a
    longer run stays in the last stage after them (how a finished run is extended)."""
    scenario: str = "small-15"
    """preset trained on when curriculum is false (ignored otherwise)."""
    mixed_scenarios: tuple[str, ...] = ()
    """presets trained on beside `scenario` when curriculum is false: B worlds of each, the batch
    steps going to them in turn, every transition into the one buffer (its rows padded to the
    most evader slots). Empty: `scenario` alone."""
    evader: str = DEFAULT_EVADER
    """the evaders trained against, in every training scenario and in the snapshots' evaluations:
    a name of terl_rt.sim.evader.EVADERS (`terl-rt scenarios --evaders`), "apf" the paper's."""
    train_max_steps: int = 3000
    """decision steps before a training episode is truncated (the published 3000)."""
    start_e: float = 0.6
    """exploration probability at step 0, per pursuer."""
    end_e: float = 0.05
    """exploration probability after the decay."""
    exploration_fraction: float = 0.25
    """fraction of total_steps over which epsilon falls linearly from start_e to end_e."""


@dataclass(frozen=True)
class RunConfig:
    """Seeding, threads, logging, checkpoints and snapshots: nothing here changes what is learnt
    except the seed."""

    seed: int = 1
    """seed of torch, NumPy (actions, exploration, replay sampling, world seeds) and Python. A
    resume continues the checkpoint's CPU generators instead; the CUDA generator (the quantile
    fractions of updates on a GPU) is not saved and is seeded anew."""
    threads: int = 1
    """torch intra-op threads, set by the command-line entry point only (one: two threads on a
    shared 2-core machine stall each other)."""
    log_frequency: int = 5000
    """environment steps between records of metrics.jsonl."""
    checkpoint_frequency: int = 20_000
    """environment steps between checkpoints (one more is written at the end)."""
    snapshot_frequency: int = 20_000
    """environment steps between snapshots: the online network is evaluated greedily
    (terl_rt.evaluation: snapshot_episodes of the current stage and of snapshot_preset, episode
    k with seed snapshot_seed + k, as `terl-rt eval`) and kept in best/ when it scores best so
    far (0: no snapshots)."""
    snapshot_episodes: int = 4
    """episodes per scenario of a snapshot evaluation."""
    snapshot_preset: str = "small-15"
    """the preset every snapshot is also evaluated on."""
    eval_seed: int = 20_240
    """seed of a snapshot's first episode (episode k: eval_seed + k)."""
    eval_max_steps: int = 1000
    """decision steps before a snapshot episode is truncated (world.md section 10)."""
    keep_snapshots: bool = False
    """also write every snapshot's online network to snapshots/<env_step>/ (about 0.5 MB each
    at H = 64), to choose among them later on larger evaluations than a snapshot's."""


SECTIONS: dict[str, type] = {
    "network": NetworkConfig,
    "learner": LearnerConfig,
    "data": DataConfig,
    "schedule": ScheduleConfig,
    "run": RunConfig,
}
"""The parts of a config by name, in the order they are written."""

RETIRED_FIELDS: dict[str, Any] = {
    "resume_reseeds": False,
    "target_tau": 0.0,
    "n_step": 1,
    "kappa": 1.0,
    "emergency_weight": 1.0,
    "team_penalty_weight": 1.0,
    "eval_frequency": None,
    "eval_episodes": None,
    "curriculum_shares": [2.0, 2.0, 1.0, 1.0, 1.0],
}
"""Knobs that no recipe uses and that did not help (docs/training-mattered.md, "Retired knobs"), with the
value that kept them out of the way: a flat config of an earlier run reads when each holds it
(None: any value, the periodic greedy evaluation it set being replaced by snapshots)."""


@dataclass(frozen=True)
class Config:
    """Everything one training run needs; the defaults are the shipped recipe's settings."""

    network: NetworkConfig = field(default_factory=NetworkConfig)
    learner: LearnerConfig = field(default_factory=LearnerConfig)
    data: DataConfig = field(default_factory=DataConfig)
    schedule: ScheduleConfig = field(default_factory=ScheduleConfig)
    run: RunConfig = field(default_factory=RunConfig)

    def __post_init__(self) -> None:
        _validate(self)

    @staticmethod
    def of(**fields: Any) -> Config:
        """The defaults with some fields changed, by field name (`Config.of(hidden=16)`)."""
        return Config().replace(**fields)

    def value(self, name: str) -> Any:
        """A field by its name, whichever part holds it."""
        if name not in SECTION_OF:
            raise ConfigError(f"unknown field '{name}'")
        return getattr(getattr(self, SECTION_OF[name]), name)

    def replace(self, **changes: Any) -> Config:
        """A validated copy with some fields changed, by field name."""
        unknown = sorted(set(changes) - set(SECTION_OF))
        if unknown:
            raise ConfigError(f"unknown field '{unknown[0]}' (known: {', '.join(SECTION_OF)})")
        parts = {
            section: dataclasses.replace(
                getattr(self, section), **{name: value for name, value in changes.items() if SECTION_OF[name] == section}
            )
            for section in SECTIONS
        }
        return Config(**parts)

    # --- serialisation
    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Every field, by part (JSON-serialisable)."""
        return {section: dataclasses.asdict(getattr(self, section)) for section in SECTIONS}

    def to_file(self, path: str | Path) -> None:
        """Write the config as an indented JSON object."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    @staticmethod
    def from_dict(data: Any, source: str = "config") -> Config:
        """Build a config from a JSON object (see `read_fields`); missing fields take the defaults."""
        fields = read_fields(data, source)
        try:
            return Config().replace(**fields)
        except ConfigError as error:
            raise ConfigError(f"{source}: {error}") from None

    @staticmethod
    def from_file(path: str | Path) -> Config:
        """Read a JSON config file (see `from_dict`)."""
        path = Path(path)
        try:
            text = path.read_text()
        except FileNotFoundError:
            raise FileNotFoundError(f"{path}: no such config file") from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as error:
            raise ConfigError(f"{path}: not valid JSON: {error}") from None
        return Config.from_dict(data, source=str(path))

    @staticmethod
    def for_model(model: str) -> Config:
        """The defaults with another network body: `model`, its layers and heads 0 when it has no
        transformer (the comparison's recipe: only the body changes)."""
        if model not in models.MODELS:
            raise ConfigError(f"model: unknown network '{model}'; expected one of {sorted(MODELS)}")
        if models.MODELS[model].transformer:
            return Config.of(model=model)
        return Config.of(model=model, layers=0, heads=0)


SECTION_OF: dict[str, str] = {
    part.name: section for section, cls in SECTIONS.items() for part in dataclasses.fields(cls)
}
"""The part that holds each field, by field name."""
FIELD_TYPES: dict[str, Any] = {
    name: hint for cls in SECTIONS.values() for name, hint in typing.get_type_hints(cls).items()
}
"""Each field's type, by field name."""

NETWORK_FIELDS = ("model", "hidden", "layers", "heads")
"""Fields that fix the network's weights: a checkpoint continues only under the same values."""

RETURN_FIELDS = (
    "reward", "potential_shaping", "collision_value", "gamma", "success_ends_transitions", "truncation_ends",
    "reward_scale",
)
"""Fields that fix what a stored transition holds (its return, discount and done): a saved
replay buffer is reused only under the same values."""

SNAPSHOT_FIELDS = (
    "curriculum", "scenario", "evader", "snapshot_preset", "snapshot_episodes", "eval_seed", "eval_max_steps",
)
"""Fields that fix what a snapshot is evaluated on: snapshot scores compare only under the same values."""


def read_fields(data: Any, source: str = "config") -> dict[str, Any]:
    """The fields a JSON object names, flat and typed: by part ({"network": {...}, ...}, as
    `Config.to_dict` writes) or flat (every field at the top level, as runs wrote before the
    split). Unknown keys, wrong types and retired knobs away from their neutral value are errors
    naming the key; retired knobs at it are dropped."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: must be a JSON object, got {type(data).__name__}")
    if any(key in SECTIONS for key in data):
        flat: dict[str, Any] = {}
        for section, values in data.items():
            if section not in SECTIONS:
                raise ConfigError(f"{source}: unknown part '{section}' (parts: {', '.join(SECTIONS)})")
            if not isinstance(values, dict):
                raise ConfigError(f"{source}: '{section}' must be an object of fields, got {values!r}")
            misplaced = sorted(name for name in values if SECTION_OF.get(name, section) != section)
            if misplaced:
                raise ConfigError(f"{source}: '{misplaced[0]}' belongs in '{SECTION_OF[misplaced[0]]}', not '{section}'")
            flat.update(values)
    else:
        flat = dict(data)
    for name, neutral in RETIRED_FIELDS.items():
        if name in flat:
            value = flat.pop(name)
            if neutral is not None and value != neutral:
                raise ConfigError(
                    f"{source}: '{name}' was retired (docs/training-mattered.md, \"Retired knobs\"); it reads only "
                    f"at {neutral!r}, got {value!r}"
                )
    unknown = sorted(set(flat) - set(SECTION_OF))
    if unknown:
        raise ConfigError(f"{source}: unknown key '{unknown[0]}' (known: {', '.join(SECTION_OF)})")
    for key, value in flat.items():
        if not _has_type(value, FIELD_TYPES[key]):
            raise ConfigError(f"{source}: '{key}' must be {_type_name(FIELD_TYPES[key])}, got {value!r}")
    return {key: _convert(value, FIELD_TYPES[key]) for key, value in flat.items()}


def changed_fields(before: Config, after: Config, names: tuple[str, ...]) -> list[str]:
    """The fields among `names` whose values differ between two configs, in the order given."""
    return [name for name in names if before.value(name) != after.value(name)]


def field_names() -> tuple[str, ...]:
    """Config field names, part by part in declaration order."""
    return tuple(SECTION_OF)


def _item_type(expected: Any) -> Any:
    """The item type of a `tuple[T, ...]` field."""
    return typing.get_args(expected)[0]


def _type_name(expected: Any) -> str:
    if typing.get_origin(expected) is tuple:
        return "a list of numbers" if _item_type(expected) is float else "a list of strings"
    return expected.__name__


def _convert(value: Any, expected: Any) -> Any:
    if typing.get_origin(expected) is tuple:
        return tuple(_item_type(expected)(v) for v in value)
    return expected(value)


def _has_type(value: Any, expected: Any) -> bool:
    """JSON value check: bool is not an int, an int is a valid float, a tuple is a list of its items."""
    if typing.get_origin(expected) is tuple:
        return isinstance(value, (list, tuple)) and all(_has_type(v, _item_type(expected)) for v in value)
    if expected is bool:
        return isinstance(value, bool)
    if isinstance(value, bool):
        return False
    if expected is float:
        return isinstance(value, (int, float))
    return isinstance(value, expected)


def _validate(config: Config) -> None:
    network, learner, data, schedule, run = config.network, config.learner, config.data, config.schedule, config.run
    if network.model not in models.MODELS:
        raise ConfigError(f"model: unknown network '{network.model}'; expected one of {sorted(MODELS)}")
    if data.reward not in REWARD_VARIANTS:
        raise ConfigError(f"reward: unknown variant '{data.reward}'; expected one of {', '.join(REWARD_VARIANTS)}")
    if run.snapshot_preset not in PRESETS:
        raise ConfigError(f"snapshot_preset: unknown preset '{run.snapshot_preset}'")
    if learner.device != "cpu" and not learner.device.startswith("cuda"):
        raise ConfigError(f"device: must be 'cpu' or 'cuda[:K]', got '{learner.device}'")
    for name, presets in (("scenario", (schedule.scenario,)), ("mixed_scenarios", schedule.mixed_scenarios)):
        for preset in presets:
            if preset not in PRESETS:
                raise ConfigError(f"{name}: unknown preset '{preset}'; presets are {', '.join(PRESETS)}")
    try:
        evader_kind(schedule.evader)
    except UnknownEvader as error:
        raise ConfigError(f"evader: {error}") from None
    if len({schedule.scenario, *schedule.mixed_scenarios}) != 1 + len(schedule.mixed_scenarios):
        raise ConfigError(f"mixed_scenarios: a preset appears twice in {[schedule.scenario, *schedule.mixed_scenarios]}")
    positive = (
        "hidden", "threads", "total_steps", "num_envs", "batch_size", "buffer_size", "train_frequency",
        "target_network_frequency", "num_quantiles", "num_target_quantiles", "eval_max_steps", "log_frequency",
        "checkpoint_frequency", "train_max_steps", "snapshot_episodes",
    )
    for name in positive:
        if config.value(name) < 1:
            raise ConfigError(f"{name}: must be >= 1, got {config.value(name)}")
    for name in ("layers", "heads", "learning_starts", "seed", "eval_seed", "curriculum_steps", "actor_update_frequency",
                 "store_pursuers", "snapshot_frequency", "decay_start", "final_learning_rate"):
        if config.value(name) < 0:
            raise ConfigError(f"{name}: must be >= 0, got {config.value(name)}")
    if models.MODELS[network.model].transformer:
        for name in ("layers", "heads"):
            if config.value(name) < 1:
                raise ConfigError(f"{name}: model '{network.model}' has a transformer, needs >= 1, got {config.value(name)}")
        if network.hidden % network.heads:
            raise ConfigError(f"heads: {network.heads} must divide hidden {network.hidden}")
    for name in ("gamma", "start_e", "end_e", "exploration_fraction", "dropout"):
        if not 0.0 <= config.value(name) <= 1.0:
            raise ConfigError(f"{name}: must lie in [0, 1], got {config.value(name)}")
    if data.potential_shaping < 0.0:
        raise ConfigError(f"potential_shaping: must be >= 0, got {data.potential_shaping}")
    if data.collision_value > 0.0:
        raise ConfigError(
            f"collision_value: must be <= 0 (a collision is never worth more than nothing), got {data.collision_value}"
        )
    for name in ("learning_rate", "max_grad_norm", "reward_scale"):
        if not config.value(name) > 0.0:
            raise ConfigError(f"{name}: must be > 0, got {config.value(name)}")
    if learner.final_learning_rate and learner.decay_start >= schedule.total_steps:
        raise ConfigError(
            f"decay_start: {learner.decay_start} must come before total_steps {schedule.total_steps} "
            "for the step size to fall to final_learning_rate"
        )
    if learner.max_per_fraction and learner.double_dqn:
        raise ConfigError("max_per_fraction: the greatest value at each fraction, or double_dqn's one online "
                          "choice for every fraction: not both")
    if learner.batch_size > data.buffer_size:
        raise ConfigError(f"batch_size: {learner.batch_size} exceeds buffer_size {data.buffer_size}")
