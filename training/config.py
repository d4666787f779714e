"""The training configuration: one dataclass, one documented field per setting.

Defaults are the published settings (policy.md section 2) for TERL. Step counts
are environment steps: one batch step of `num_envs` vectorised environments is
`num_envs` environment steps, the way the paper counts the steps of its single
environment. Each environment step stores one transition per active pursuer.
"""

from __future__ import annotations

import dataclasses
import json
import typing
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from terl_rt.sim.reward import REWARD_VARIANTS
from terl_rt.sim.scenario import CURRICULUM_STARTS, PRESETS

CURRICULUM_STAGES = tuple(name for _, name in CURRICULUM_STARTS)
"""The curriculum's stage presets, in order (world.md section 11)."""


class ConfigError(ValueError):
    """A configuration that is malformed; the message names the field (or file)."""


@dataclass(frozen=True)
class Config:
    """Everything one training run needs, with the published defaults."""

    # --- network
    model: str = "terl"
    """network registry name: terl, iqn, dqn, mean, terl-no-re or terl-no-ts."""
    hidden: int = 256
    """H: token and feature width."""
    layers: int = 4
    """L: transformer layers (0 for bodies without a transformer)."""
    heads: int = 8
    """h: attention heads, must divide H (0 for bodies without a transformer)."""
    dropout: float = 0.1
    """dropout probability inside the transformer layers while learning (the published 0.1;
    on CPUs its random numbers cost about a third of an update)."""

    # --- run
    seed: int = 1
    """seed of torch, NumPy (actions, exploration, replay sampling, world seeds) and Python.
    A resume, a fine-tune included, continues the checkpoint's CPU generators instead, unless
    `resume_reseeds`: on the CPU, changing the seed there does not start another sample of the
    run. The CUDA generator (the quantile fractions of updates on a GPU) is not saved and is
    seeded anew, so on a GPU it does."""
    resume_reseeds: bool = False
    """a resume seeds Python's, NumPy's and torch's generators anew from `seed` instead of
    continuing the checkpoint's: fine-tunes from one checkpoint with other seeds are other
    samples of the run (other worlds, exploration and replay draws). Off, a resume continues
    the run bit for bit."""
    threads: int = 2
    """torch intra-op threads, set by the command-line entry point only."""
    total_steps: int = 7_000_000
    """length of training in environment steps (num_envs per batch step)."""
    num_envs: int = 8
    """B: environments stepped together; one batched forward acts for all their pursuers."""
    curriculum: bool = True
    """walk the five curriculum stages (world.md section 11), scaled to curriculum_steps."""
    curriculum_steps: int = 0
    """environment steps the curriculum's stage boundaries are scaled to (0: total_steps);
    a longer run stays in the last stage after them (how a finished run is extended)."""
    scenario: str = "small-15"
    """preset trained on when curriculum is false (ignored otherwise)."""
    mixed_scenarios: tuple[str, ...] = ()
    """presets trained on beside `scenario` when curriculum is false: B worlds of each, the
    batch steps going to `scenario`'s worlds and these in turn, every transition into the one
    replay buffer, so no stretch of updates sees one team size alone (empty: `scenario`
    alone). The buffer rows take the most evader slots of them, the others padded with empty slots."""
    curriculum_shares: tuple[float, ...] = (2.0, 2.0, 1.0, 1.0, 1.0)
    """share of curriculum_steps each of the five stages gets, in stage order (normalised;
    the published 2 M / 2 M / 1 M / 1 M / 1 M of 7 M)."""
    train_max_steps: int = 3000
    """decision steps before a training episode is truncated (the published 3000)."""
    reward: str = "paper"
    """reward variant of the training worlds (world.md section 9): "paper" or "published"."""

    # --- learning (policy.md section 2)
    gamma: float = 0.99
    """discount factor per decision step (0.5 s), in [0, 1]."""
    learning_rate: float = 1e-4
    """Adam step size (the first, when final_learning_rate is set)."""
    final_learning_rate: float = 0.0
    """0: the step size stays learning_rate. > 0: it falls linearly from learning_rate at
    environment step decay_start to final_learning_rate at total_steps."""
    decay_start: int = 0
    """environment step at which the final_learning_rate decay begins (a fine-tune sets the
    step it resumes from; a resume of the same run then keeps the same schedule)."""
    batch_size: int = 128
    """transitions (pursuer rows) per gradient update."""
    max_grad_norm: float = 0.5
    """global gradient-norm clip."""
    buffer_size: int = 1_000_000
    """replay capacity in pursuer transitions (about 1 KB each)."""
    learning_starts: int = 3000
    """environment steps collected before the first update (again after a resume)."""
    train_frequency: int = 4
    """environment steps per gradient update: a batch step of B envs runs the
    updates whose multiples of train_frequency it crossed (B/4 on average)."""
    target_network_frequency: int = 10_000
    """environment steps between hard copies of the online network to the target (unused
    when target_tau > 0)."""
    actor_update_frequency: int = 0
    """0: the online network acts, changing with every update (the published setting). K > 0: a
    copy of it acts, refreshed every K environment steps (and at a resume), so the data come from
    one fixed network K steps at a time. A network that works only while it changes (with 2
    updates every batch step the greedy action among near-equal Q-values moves all the time)
    then meets the states where it stalls, and learns their values (docs/training.md, "Values
    that track the returns"). A resume continues bit for bit when checkpoint_frequency is a
    multiple of K."""
    target_tau: float = 0.0
    """tau: 0 copies the online network whole into the target every target_network_frequency
    steps (the published setting); tau in (0, 1] moves the target after every update instead,
    target <- tau * online + (1 - tau) * target (a soft, Polyak update: it trails the online
    network by about 1 / tau updates)."""
    start_e: float = 0.6
    """exploration probability at step 0, per pursuer."""
    end_e: float = 0.05
    """exploration probability after the decay."""
    exploration_fraction: float = 0.25
    """fraction of total_steps over which epsilon falls linearly from start_e to end_e."""
    num_quantiles: int = 8
    """N: fractions sampled for the online quantiles of each transition (unused by dqn)."""
    num_target_quantiles: int = 8
    """N': fractions sampled for the target quantiles (unused by dqn)."""
    kappa: float = 1.0
    """threshold of the (quantile) Huber loss, in return units."""
    success_ends_transitions: bool = False
    """true: an episode that terminates (the last evader encircled, or fewer than 3 pursuers
    left) ends its surviving pursuers' transitions at 0 (no bootstrap); false: they are
    bootstrapped, as the published trainer does (with true, in stage 1 one crash paid its two
    teammates for ending a bad episode). Collisions always end a pursuer's transition; the step
    limit never does (truncation is bootstrapped)."""
    reward_scale: float = 1.0
    """c: every taught reward, and the collision value, times c, so returns (and Q) are in units of
    1 / c: with c = 1/20 the returns of -125 to -300 a pursuer come to -6 to -15, where the
    quantile Huber threshold kappa = 1 and Adam's step size work (docs/training.md, "Values that
    track the returns"). The greedy policy is the same for any c > 0."""
    double_dqn: bool = False
    """double-DQN targets: the online network picks the next action, the target network
    values it (the published trainer takes the target network's own max)."""
    n_step: int = 1
    """n: rewards summed over up to n steps before bootstrapping with gamma^n (fewer at the
    end of a pursuer's episode)."""
    potential_shaping: float = 0.0
    """k: 0 trains on the reward as the variant pays it. k > 0 pays its guidance term and the
    positive part of its cooperation term as a potential difference instead,
    gamma * Phi(s') - Phi(s) with Phi = k * (guidance + max(cooperation, 0)) of the state a
    step ends in (Phi(s') = 0 after a terminal transition, Phi = 0 before an episode's first
    step): holding a ring open then earns nothing a step, the approach still pays, and the
    best policy of the other terms (time, collision, emergency, boundary, crowding,
    completion) is unchanged (potential-based shaping, Ng, Harada and Russell 1999)."""
    collision_value: float = 0.0
    """V_c: the value a collided pursuer's (terminal) transition ends on, in return units: its
    stored return gains gamma * V_c in the step it collides (0: nothing, the published setting).
    Under either reward variant a collision ends a pursuer's time, emergency and crowding
    penalties, so in a crowded endgame the -80 of a collision costs little more than staying.
    V_c = -100 = -1 / (1 - gamma) charges the dead pursuer the time term for ever; a collision
    still pays wherever a living pursuer expects less than V_c (crowds of 48-80 pursuers and
    the first curriculum stages, at about -3 a step, return about -300: docs/training.md),
    so V_c must lie below the returns of the run's worlds."""
    emergency_weight: float = 1.0
    """w_e: the emergency term (world.md section 9: -5 a step while closer than d_safe = 4 m to
    an active teammate, active evader or perceived obstacle) is taught times w_e (1: as the
    variant pays it). Nine collisions in ten are two pursuers touching in the crowd at a ring
    (docs/training.md), where the emergency term is the only price of closing in that a
    pursuer pays before touching; w_e > 1 raises that price and changes what is optimal,
    unlike potential_shaping."""
    team_penalty_weight: float = 1.0
    """w_t: the team-wide share of the cooperation term (`paper`: the imbalance penalty, -10 to
    every pursuer while one evader has fewer than 3 pursuers near and another more than 5;
    `published`: -10 to every pursuer while any evader has 5 or more) is taught times w_t (1: as
    the variant pays it). That share depends on pursuers a pursuer cannot see, and in teams of
    48-80 it holds the returns near -300, below the value a collision ends on; w_t < 1 teaches
    less of it and changes what is optimal, unlike potential_shaping."""
    store_pursuers: int = 0
    """pursuer transitions of each world step that enter the replay buffer, a random subset
    of the pursuers that acted (0: all of them, the published setting)."""
    device: str = "cpu"
    """torch device of the networks and updates ("cpu", "cuda"); rollouts stay on the CPU."""
    bf16: bool = False
    """run the network body of updates under bfloat16 autocast (the IQN head's output layer and
    the loss stay float32); acting stays float32. With TERL H = 64 on one thread of these
    AVX-512 BF16 CPUs an update is 1.11x faster than trimmed float32 (`python -m training
    bench`); bf16 keeps about 3 significant digits."""

    # --- evaluation, logging, checkpoints
    eval_frequency: int = 100_000
    """environment steps between greedy evaluations (0: never)."""
    eval_episodes: int = 4
    """episodes per evaluation, run as one batch on fixed seeds."""
    eval_seed: int = 20_240
    """seed of the evaluation episodes (the same episodes every time for a stage)."""
    eval_max_steps: int = 1000
    """decision steps before an evaluation episode is truncated (world.md section 10)."""
    log_frequency: int = 10_000
    """environment steps between records of metrics.jsonl."""
    checkpoint_frequency: int = 100_000
    """environment steps between checkpoints (one more is written at the end)."""
    save_replay: bool = True
    """save the replay buffer with every checkpoint (replay.npz, beside it): a resume on the
    same machine continues with it; without it the buffer is refilled first."""
    snapshot_frequency: int = 0
    """environment steps between snapshots: the online network is evaluated greedily
    (snapshot_episodes on fixed seeds of the current stage and of snapshot_preset) and
    kept in best/ when it scores best so far (0: no snapshots)."""
    snapshot_episodes: int = 8
    """episodes per scenario of a snapshot evaluation."""
    snapshot_preset: str = "medium-48"
    """the larger preset every snapshot is also evaluated on."""
    keep_snapshots: bool = False
    """also write every snapshot's online network to snapshots/<env_step>/ (about 0.5 MB
    each at H = 64), to choose among them later on larger evaluations than a snapshot's."""

    def __post_init__(self) -> None:
        _validate(self)

    # --- construction and serialisation
    @staticmethod
    def from_dict(data: Any, source: str = "config") -> Config:
        """Build a config from a JSON object; unknown keys and wrong types are errors naming the key.

        Missing keys take the defaults above.
        """
        if not isinstance(data, dict):
            raise ConfigError(f"{source}: must be a JSON object, got {type(data).__name__}")
        types = typing.get_type_hints(Config)
        unknown = sorted(set(data) - set(types))
        if unknown:
            raise ConfigError(
                f"{source}: unknown key '{unknown[0]}' (known: {', '.join(field_names())})"
            )
        for key, value in data.items():
            if not _has_type(value, types[key]):
                raise ConfigError(
                    f"{source}: '{key}' must be {_type_name(types[key])}, got {value!r}"
                )
        try:
            return Config(**{key: _convert(value, types[key]) for key, value in data.items()})
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
        """The packaged config training/configs/<model>.json (published defaults for that model)."""
        names = packaged_configs()
        if model not in names:
            raise ConfigError(f"no packaged config for model '{model}'; expected one of {names}")
        text = resources.files("training").joinpath("configs", f"{model}.json").read_text()
        return Config.from_dict(json.loads(text), source=f"training/configs/{model}.json")

    def to_dict(self) -> dict[str, Any]:
        """Every field by name (JSON-serialisable)."""
        return dataclasses.asdict(self)

    def to_file(self, path: str | Path) -> None:
        """Write the config as an indented JSON object."""
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n")

    def replace(self, **changes: Any) -> Config:
        """A validated copy with some fields changed."""
        return dataclasses.replace(self, **changes)


NETWORK_FIELDS = ("model", "hidden", "layers", "heads")
"""Fields that fix the network's weights: a checkpoint continues only under the same values."""

RETURN_FIELDS = (
    "reward", "potential_shaping", "collision_value", "emergency_weight", "team_penalty_weight", "gamma", "n_step",
    "success_ends_transitions", "reward_scale",
)
"""Fields that fix what a stored transition holds (its return, discount and done): a saved
replay buffer is reused only under the same values."""

SNAPSHOT_FIELDS = ("curriculum", "scenario", "snapshot_preset", "snapshot_episodes", "eval_seed", "eval_max_steps")
"""Fields that fix what a snapshot is evaluated on: snapshot scores compare only under the same values."""


def changed_fields(before: Config, after: Config, names: tuple[str, ...]) -> list[str]:
    """The fields among `names` whose values differ between two configs, in the order given."""
    return [name for name in names if getattr(before, name) != getattr(after, name)]


def field_names() -> tuple[str, ...]:
    """Config field names, in declaration order."""
    return tuple(f.name for f in dataclasses.fields(Config))


def packaged_configs() -> tuple[str, ...]:
    """Model names with a config file under training/configs/."""
    folder = resources.files("training").joinpath("configs")
    names = (entry.name for entry in folder.iterdir())
    return tuple(sorted(name[: -len(".json")] for name in names if name.endswith(".json")))


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
    # Imported here: the registry pulls in torch, which `Config` users may not need yet.
    from training.networks import network_classes

    models = sorted(network_classes())
    if config.model not in models:
        raise ConfigError(f"model: unknown network '{config.model}'; expected one of {models}")
    if config.reward not in REWARD_VARIANTS:
        raise ConfigError(f"reward: unknown variant '{config.reward}'; expected one of {', '.join(REWARD_VARIANTS)}")
    if len(config.curriculum_shares) != len(CURRICULUM_STAGES) or not all(
        share > 0 for share in config.curriculum_shares
    ):
        raise ConfigError(
            f"curriculum_shares: must be {len(CURRICULUM_STAGES)} positive numbers, got {list(config.curriculum_shares)}"
        )
    if config.snapshot_preset not in PRESETS:
        raise ConfigError(f"snapshot_preset: unknown preset '{config.snapshot_preset}'")
    if config.device != "cpu" and not config.device.startswith("cuda"):
        raise ConfigError(f"device: must be 'cpu' or 'cuda[:K]', got '{config.device}'")
    for field, names in (("scenario", (config.scenario,)), ("mixed_scenarios", config.mixed_scenarios)):
        for name in names:
            if name not in PRESETS:
                raise ConfigError(f"{field}: unknown preset '{name}'; presets are {', '.join(PRESETS)}")
    if len(set((config.scenario,) + config.mixed_scenarios)) != 1 + len(config.mixed_scenarios):
        raise ConfigError(f"mixed_scenarios: a preset appears twice in {[config.scenario, *config.mixed_scenarios]}")
    positive = (
        "hidden", "threads", "total_steps", "num_envs", "batch_size", "buffer_size",
        "train_frequency", "target_network_frequency", "num_quantiles",
        "num_target_quantiles", "eval_episodes", "eval_max_steps", "log_frequency",
        "checkpoint_frequency", "train_max_steps", "n_step", "snapshot_episodes",
    )
    for name in positive:
        if getattr(config, name) < 1:
            raise ConfigError(f"{name}: must be >= 1, got {getattr(config, name)}")
    for name in ("layers", "heads", "learning_starts", "eval_frequency", "seed", "eval_seed", "curriculum_steps",
                 "actor_update_frequency",
                 "store_pursuers", "snapshot_frequency", "decay_start", "final_learning_rate",
                 "emergency_weight", "team_penalty_weight"):
        if getattr(config, name) < 0:
            raise ConfigError(f"{name}: must be >= 0, got {getattr(config, name)}")
    # A tiny probe tells transformer bodies (which record their layers) from the others.
    if network_classes()[config.model](hidden=4, layers=1, heads=1).num_layers > 0:
        for name in ("layers", "heads"):
            if getattr(config, name) < 1:
                raise ConfigError(
                    f"{name}: model '{config.model}' has a transformer, needs >= 1, got {getattr(config, name)}"
                )
        if config.hidden % config.heads:
            raise ConfigError(f"heads: {config.heads} must divide hidden {config.hidden}")
    for name in ("gamma", "start_e", "end_e", "exploration_fraction", "dropout", "target_tau"):
        if not 0.0 <= getattr(config, name) <= 1.0:
            raise ConfigError(f"{name}: must lie in [0, 1], got {getattr(config, name)}")
    if config.potential_shaping < 0.0:
        raise ConfigError(f"potential_shaping: must be >= 0, got {config.potential_shaping}")
    if config.collision_value > 0.0:
        raise ConfigError(f"collision_value: must be <= 0 (a collision is never worth more than nothing), got {config.collision_value}")
    for name in ("learning_rate", "max_grad_norm", "kappa", "reward_scale"):
        if not getattr(config, name) > 0.0:
            raise ConfigError(f"{name}: must be > 0, got {getattr(config, name)}")
    if config.final_learning_rate and config.decay_start >= config.total_steps:
        raise ConfigError(
            f"decay_start: {config.decay_start} must come before total_steps {config.total_steps} "
            "for the step size to fall to final_learning_rate"
        )
    if config.batch_size > config.buffer_size:
        raise ConfigError(
            f"batch_size: {config.batch_size} exceeds buffer_size {config.buffer_size}"
        )
