"""The world as a PettingZoo `ParallelEnv` (the `pettingzoo` extra: pettingzoo, gymnasium).

    from terl_rt.envs import parallel_env
    env = parallel_env("small-15")
    observations, infos = env.reset(seed=0)
    while env.agents:
        actions = {agent: env.action_space(agent).sample() for agent in env.agents}
        observations, rewards, terminations, truncations, infos = env.step(actions)

As PettingZoo's own environments: `parallel_env(...)` is the parallel API, `env(...)` the
AEC API (agents act in turn; `parallel_to_aec` of it, order-enforced) and `raw_env(...)`
the same without the order check.

Agents are `pursuer_0` .. `pursuer_{N-1}`. Each observes a Dict of the ONNX contract's
groups (docs/policy.md section 3): `ego` [4], `teammates` [5, 7], `evaders` [E, 7],
`obstacles` [5, 5] (float32) and `mask` [1 + 5 + E + 5] (MultiBinary, bool values), and
acts with one of 9 discrete actions. A pursuer that collides is terminated and leaves
`agents`; when the task ends (every evader encircled, or fewer than 3 pursuers left)
every remaining pursuer is terminated; the scenario's step limit truncates them.
`infos[agent]` holds the reward terms of the step, the pursuer's index and, at the end,
the episode's metrics.

`state()` is the global state for centralised training (TorchRL, BenchMARL): one float32
vector in `state_space`, the world's public state (`terl_rt.sim.state.LOGGED_FIELDS`, in
that order, each flattened: positions as x, y pairs in m, headings in rad, speeds in m/s,
active flags as 0/1, the step count last); `world_state()` gives the same as named arrays.

Seeds follow `Simulator`: an int, a np.random.Generator (one draw gives the int) or None
(fresh entropy); `reset(seed=...)` starts that seed's stream of episodes, `reset()` the
next episode of the current one.

`ShieldedParallelEnv(env, shield)` wears the shield (terl_rt.safety.shield) over the actions
given to `step`: each live pursuer's action is checked against its last observation, an
unsafe one replaced by the kept action of largest clearance, and
`infos[agent]["shield_overrode"]` says where that happened.

The wrapper holds a one-environment `terl_rt.sim.world.World` and only translates
between its arrays and PettingZoo's dicts: the rules live in the world alone, and the
batched `World` stays the fast path for many environments at once. Same scenario, seed
and actions give the same episode as `Simulator(scenario, seed)`.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import SimpleNamespace
from typing import Any

import numpy as np

from terl_rt.extras import install_hint

try:
    from gymnasium import spaces
    from pettingzoo import AECEnv, ParallelEnv
    from pettingzoo.utils.conversions import parallel_to_aec, parallel_to_aec_wrapper
    from pettingzoo.utils.wrappers import BaseParallelWrapper
except ImportError as error:  # pragma: no cover - exercised without the extra
    raise ImportError(
        f"terl_rt.envs needs the pettingzoo extra: {install_hint('pettingzoo')}"
    ) from error

from terl_rt.safety.shield import Shield, shield_actions
from terl_rt.sim.actions import NUM_PURSUER_ACTIONS
from terl_rt.sim.evader import EvaderPolicy
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.observation import (
    EGO_FEATURES, EVADER_FEATURES, OBSTACLE_FEATURES, OBSTACLE_SLOTS, TEAMMATE_FEATURES, TEAMMATE_SLOTS, Observation,
)
from terl_rt.sim.reward import REWARD_TERMS
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.state import LOGGED_FIELDS, snapshot
from terl_rt.sim.world import Seed, World

RENDER_MODES = ("rgb_array",)


def parallel_env(
    scenario: Scenario | str = "small-15",
    seed: Seed = None,
    render_mode: str | None = None,
    evader_policy: EvaderPolicy | None = None,
    max_steps: int | None = None,
    render_size: int = 480,
) -> TerlParallelEnv:
    """A PettingZoo ParallelEnv of `scenario` (a Scenario or a preset name).

    seed: the episode stream's seed until `reset(seed=...)` picks another (an int, a
    np.random.Generator or None: fresh entropy, as `Simulator`); max_steps overrides the
    scenario's step limit; render_mode "rgb_array" makes `render()` return an
    [H, W, 3] uint8 frame `render_size` px wide.
    """
    return TerlParallelEnv(scenario, seed, render_mode, evader_policy, max_steps, render_size)


def raw_env(*args: Any, **kwargs: Any) -> AECEnv:
    """The AEC form of `parallel_env(...)` (pursuers act in turn; its arguments, the scenario
    first), without PettingZoo's order-enforcing wrapper."""
    return parallel_to_aec_wrapper(parallel_env(*args, **kwargs))


def env(*args: Any, **kwargs: Any) -> AECEnv:
    """The AEC form of `parallel_env(...)` (its arguments, the scenario first), as
    PettingZoo's own `env()` constructors return it: `parallel_to_aec`, with the
    order-enforcing wrapper."""
    return parallel_to_aec(parallel_env(*args, **kwargs))


class TerlParallelEnv(ParallelEnv):
    """See the module docstring. Build it with `parallel_env(...)`."""

    metadata = {"name": "terl_encirclement_v0", "render_modes": list(RENDER_MODES), "render_fps": 2}

    def __init__(
        self,
        scenario: Scenario | str,
        seed: Seed = None,
        render_mode: str | None = None,
        evader_policy: EvaderPolicy | None = None,
        max_steps: int | None = None,
        render_size: int = 480,
    ) -> None:
        if isinstance(scenario, str):
            scenario = Scenario.preset(scenario)
        if not isinstance(scenario, Scenario):
            raise TypeError(f"scenario must be a Scenario or a preset name, got {_shown(scenario)}")
        if max_steps is not None:
            scenario = scenario.replace(max_steps=_integer("max_steps", max_steps))
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode must be one of {RENDER_MODES} or None, got {render_mode!r:.60}")
        self.scenario = scenario
        self.render_mode = render_mode
        self.render_size = _render_size(render_size)
        self.possible_agents = [f"pursuer_{i}" for i in range(scenario.pursuers)]
        self.agents: list[str] = []
        self._index = {agent: i for i, agent in enumerate(self.possible_agents)}
        self._world = World(scenario, num_envs=1, seed=seed, evader_policy=evader_policy)
        self._episodes = 0
        self._history: list[dict[str, np.ndarray]] = []
        slots = scenario.evader_slots
        self._observation_space = spaces.Dict({
            "ego": spaces.Box(-np.inf, np.inf, (EGO_FEATURES,), np.float32),
            "teammates": spaces.Box(-np.inf, np.inf, (TEAMMATE_SLOTS, TEAMMATE_FEATURES), np.float32),
            "evaders": spaces.Box(-np.inf, np.inf, (slots, EVADER_FEATURES), np.float32),
            "obstacles": spaces.Box(-np.inf, np.inf, (OBSTACLE_SLOTS, OBSTACLE_FEATURES), np.float32),
            "mask": spaces.MultiBinary(1 + TEAMMATE_SLOTS + slots + OBSTACLE_SLOTS),
        })
        self._action_space = spaces.Discrete(NUM_PURSUER_ACTIONS)
        self._observation_spaces = {agent: self._observation_space for agent in self.possible_agents}
        self._action_spaces = {agent: spaces.Discrete(NUM_PURSUER_ACTIONS) for agent in self.possible_agents}
        self.state_space = spaces.Box(-np.inf, np.inf, (state_size(scenario),), np.float32)
        """The space of `state()`: [S] float32, S = `state_size(scenario)`."""

    # ------------------------------------------------------------------ spaces
    def observation_space(self, agent: str) -> spaces.Dict:
        return self._observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Discrete:
        return self._action_spaces[agent]

    @property
    def world(self) -> World:
        """The one-environment World underneath (read its `state`; do not step it)."""
        return self._world

    # ------------------------------------------------------------------ episode
    def reset(self, seed: Seed = None, options: dict | None = None) -> tuple[dict, dict]:
        """Start an episode: the next of the stream, or the first of `seed`'s stream (an
        int, or a np.random.Generator that gives one)."""
        if seed is not None:
            self._episodes = 0
        observation = self._world.reset(seed=seed)
        self._episodes += 1
        self.agents = list(self.possible_agents)
        self._history = [snapshot(self._world.state, 0)] if self.render_mode else []
        observations = {agent: self._observe(observation, i) for agent, i in self._index.items()}
        infos = {agent: {"pursuer_index": i} for agent, i in self._index.items()}
        return observations, infos

    def step(self, actions: Mapping[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        """One decision step (0.5 s) for the live agents; returns observations, rewards,
        terminations, truncations and infos of the agents that were live before it."""
        if not isinstance(actions, Mapping):
            raise TypeError(f"step: actions must be a dict of agent name -> action index, got {_shown(actions)}")
        if not self.agents:
            raise RuntimeError("step: the episode ended (no live agents); call reset()")
        live = list(self.agents)
        missing = [agent for agent in live if agent not in actions]
        if missing:
            raise ValueError(f"step: no action for live agents {missing}")
        unknown = [agent for agent in actions if agent not in self._index]
        if unknown:
            raise ValueError(f"step: unknown agents {unknown}")
        chosen = np.zeros((1, self.scenario.pursuers), np.int64)
        for agent in live:
            chosen[0, self._index[agent]] = _action(agent, actions[agent])
        observation, result = self._world.step(chosen)
        if self.render_mode:
            self._history.append(snapshot(self._world.state, 0))

        ended = bool(result.terminated[0])
        truncated_all = bool(result.truncated[0])
        metrics = self._world.metrics(0) if ended or truncated_all else None
        observations, rewards, terminations, truncations, infos = {}, {}, {}, {}, {}
        for agent in live:
            i = self._index[agent]
            observations[agent] = self._observe(observation, i)
            rewards[agent] = float(result.reward[0, i])
            terminations[agent] = ended or bool(result.collided[0, i])
            truncations[agent] = truncated_all and not terminations[agent]
            info: dict[str, Any] = {
                "pursuer_index": i,
                "reward_terms": {name: float(result.reward_terms[0, i, k]) for k, name in enumerate(REWARD_TERMS)},
                "collided": bool(result.collided[0, i]),
                "target": int(result.pursuer_target[0, i]),
            }
            if metrics is not None:
                info["metrics"] = metrics.to_dict()
            infos[agent] = info
        self.agents = [agent for agent in live if not (terminations[agent] or truncations[agent])]
        return observations, rewards, terminations, truncations, infos

    def metrics(self) -> EpisodeMetrics:
        """Success, travel time, collision ratio and counts of the episode so far."""
        return self._world.metrics(0)

    def state(self) -> np.ndarray:
        """The global state, [S] float32 in `state_space`: `world_state()`'s arrays of
        LOGGED_FIELDS flattened in order (bools as 0/1)."""
        named = self.world_state()
        return np.concatenate([np.asarray(named[f.key], np.float32).ravel() for f in LOGGED_FIELDS])

    def world_state(self) -> dict[str, np.ndarray]:
        """Copies of the world's arrays by name, as `Simulator.state()`."""
        if self._world.state is None:
            raise RuntimeError("state: call reset() first")
        return snapshot(self._world.state, 0)

    # ------------------------------------------------------------------ render
    def render(self) -> np.ndarray | None:
        """The current frame as an [H, W, 3] uint8 array (render_mode "rgb_array"), drawn
        as `terl-rt render` draws a logged episode; None without a render mode."""
        if self.render_mode is None:
            return None
        if not self._history:
            raise RuntimeError("render: call reset() first")
        from terl_rt.logs.render import draw_state  # Pillow; imported only when drawing

        finished = not self.agents and len(self._history) > 1
        episode = SimpleNamespace(
            scenario=self.scenario, number=self._episodes - 1, seed=self._world.seed,
            metrics=self._world.metrics(0) if finished else None,
        )
        return np.asarray(draw_state(self._history, len(self._history) - 1, episode, self.render_size, final=finished))

    def close(self) -> None:
        self._history = []

    def _observe(self, observation: Observation, i: int) -> dict[str, np.ndarray]:
        return {
            "ego": observation.ego[0, i],
            "teammates": observation.teammates[0, i],
            "evaders": observation.evaders[0, i],
            "obstacles": observation.obstacles[0, i],
            "mask": observation.mask[0, i],
        }


class ShieldedParallelEnv(BaseParallelWrapper):
    """`env` (a `TerlParallelEnv`) under the shield: `step` replaces each live pursuer's
    unsafe action, judged from the observation it was given last, by the kept action of
    largest clearance (the action given is all a dict of actions says of a preference), and
    adds `shield_overrode` (bool) to every agent's info. Everything else is `env`'s."""

    def __init__(self, env: TerlParallelEnv, shield: Shield | None = None) -> None:
        if not isinstance(env, TerlParallelEnv):
            raise TypeError(f"ShieldedParallelEnv wraps a TerlParallelEnv (terl_rt.envs.parallel_env), got {_shown(env)}")
        super().__init__(env)
        self.shield = Shield() if shield is None else shield
        self._last: dict[str, dict[str, np.ndarray]] = {}
        self._number = {agent: i for i, agent in enumerate(env.possible_agents)}

    def reset(self, seed: Seed = None, options: dict | None = None) -> tuple[dict, dict]:
        observations, infos = self.env.reset(seed=seed, options=options)
        self._last = observations
        return observations, infos

    def step(self, actions: Mapping[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        """`env.step` with the shield's actions; the checks of `env.step` come first."""
        if not isinstance(actions, Mapping) or not self.env.agents:
            return self.env.step(actions)  # its own error
        live = [agent for agent in self.env.agents if agent in actions]
        given = np.array([_action(agent, actions[agent]) for agent in live], np.int64)
        rows = Observation(
            **{name: np.stack([self._last[agent][name] for agent in live]) for name in self._last[live[0]]},
            pursuer_index=np.array([self._number[agent] for agent in live]),
        ) if live else None
        chosen, overrode = (given, np.zeros(0, bool)) if rows is None else shield_actions(
            rows, given, None, self.env.scenario.params, self.shield)
        observations, rewards, terminations, truncations, infos = self.env.step(
            {**actions, **dict(zip(live, chosen.tolist()))})
        flags = dict(zip(live, overrode.tolist()))
        for agent, info in infos.items():
            info["shield_overrode"] = flags.get(agent, False)
        self._last = observations
        return observations, rewards, terminations, truncations, infos


def _shown(value: Any) -> str:
    """`value`'s type and repr, cut to 60 characters: what an error message shows of it."""
    return f"{type(value).__name__} {value!r:.60}"


def _integer(name: str, value: Any) -> int:
    """`value` as an int when it is one (a Python or NumPy integer, not a bool); TypeError
    naming `name` otherwise: 2.5, "3" and True are mistakes, not integers."""
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value[()]
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an integer, got {_shown(value)}")
    return int(value)


def _action(agent: str, value: Any) -> int:
    """An agent's action: an integer in [0, NUM_PURSUER_ACTIONS); TypeError or ValueError
    naming the agent and the value otherwise."""
    action = _integer(f"step: the action of {agent}", value)
    if not 0 <= action < NUM_PURSUER_ACTIONS:
        raise ValueError(f"step: the action of {agent} must lie in [0, {NUM_PURSUER_ACTIONS}), got {action!r:.60}")
    return action


def _render_size(value: Any) -> int:
    """render_size in px, within `terl_rt.logs.render.SIZE_RANGE`."""
    from terl_rt.logs.render import SIZE_RANGE  # Pillow: imported here, not with this module

    size = _integer("render_size", value)
    if not SIZE_RANGE[0] <= size <= SIZE_RANGE[1]:
        raise ValueError(f"render_size must lie in [{SIZE_RANGE[0]}, {SIZE_RANGE[1]}] px, got {size!r:.60}")
    return size


def state_size(scenario: Scenario) -> int:
    """S, the length of `TerlParallelEnv.state()` for `scenario`: each LOGGED_FIELDS array
    of N pursuers, M evaders, O obstacles or V vortices (x, y pairs count twice), plus 1
    for the step count."""
    counts = {
        "pursuer": scenario.pursuers, "evader": scenario.evaders,
        "obstacle": scenario.obstacles, "vortex": scenario.vortices, "step": 1,
    }
    return sum(counts[f.key.split("_")[0]] * (2 if f.pairs else 1) for f in LOGGED_FIELDS)
