"""A batch of B independent worlds of one scenario, stepped together (training throughput).

Letters: B environments, N pursuers, M evaders. The step is a few named phases:
evaders decide, everyone moves, collisions, encirclement, rewards, episode end,
observations. Every phase is array operations over all robots of all environments.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terl_rt.sim.actions import EVADER_ACTIONS, NUM_EVADER_ACTIONS, NUM_PURSUER_ACTIONS, PURSUER_ACTIONS
from terl_rt.sim.collisions import collisions
from terl_rt.sim.dynamics import as_pairs, integrate, signed_circulation
from terl_rt.sim.encirclement import encircle, remember_perceived
from terl_rt.sim.evader import EvaderPolicy, build_evader
from terl_rt.sim.geometry import Geometry
from terl_rt.sim.metrics import EpisodeMetrics, episode_metrics
from terl_rt.sim.observation import Observation, pursuer_observations, pursuit_status
from terl_rt.sim.reset import Placement, place
from terl_rt.sim.reward import first_perceived_obstacle_distance, paper_reward_terms, published_reward_terms
from terl_rt.sim.scenario import Scenario
from terl_rt.sim.state import WorldState


WORLD_VERSION = "2"
"""Version of the world's rules, recorded in episode logs: a log of another version is not
re-simulated (its episodes would differ). 1: until 2026-11-23. 2: the published world
exactly: steer-only velocity at reset, a collided pursuer still counts in its step and
keeps testing encirclements, pursuit status as published (world.md sections 2, 5-7)."""


@dataclass(frozen=True)
class StepResult:
    """What one step of a batch did. Shapes [B, ...]."""

    reward: np.ndarray
    """[B, N] float64: total reward of each pursuer (0 for those inactive at the step start)."""
    reward_terms: np.ndarray
    """[B, N, 7] float64: the terms, in terl_rt.sim.reward.REWARD_TERMS order."""
    team_cooperation: np.ndarray
    """[B] float64: the share of the cooperation term paid alike to every pursuer of a world that
    acted, whatever it did (paper: the imbalance penalty; published: the crowding penalty);
    included in reward_terms."""
    acted: np.ndarray
    """[B, N] bool: pursuers active at the step start (they acted and get a reward)."""
    collided: np.ndarray
    """[B, N] bool: pursuers that collided in this step."""
    captured: np.ndarray
    """[B, M] bool: evaders encircled in this step."""
    pursuer_target: np.ndarray
    """[B, N] int64: evader each pursuer encircled in this step, -1 for none."""
    evader_actions: np.ndarray
    """[B, M] int64: the evaders' action indices."""
    terminated: np.ndarray
    """[B] bool: the task ended (all evaders encircled, or too few pursuers left)."""
    truncated: np.ndarray
    """[B] bool: the step limit was reached first."""
    success: np.ndarray
    """[B] bool: every evader is encircled."""


def _initial_state(scenario: Scenario, placements: list[Placement]) -> WorldState:
    """Stack per-environment placements into a state.

    A robot's velocity at reset is its steer velocity alone, s (cos theta, sin theta):
    the published simulator computes it before the vortex cores exist (world.md section 2).
    """
    def stack(group: str) -> np.ndarray:
        return np.stack([getattr(pl, group) for pl in placements])

    pursuers, evaders = stack("pursuers"), stack("evaders")
    obstacles, vortices = stack("obstacles"), stack("vortices")
    num_envs = len(placements)
    pursuer_theta, evader_theta = np.mod(pursuers[..., 2], 2 * np.pi), np.mod(evaders[..., 2], 2 * np.pi)
    return WorldState(
        pursuer_xy=pursuers[..., :2].copy(),
        pursuer_theta=pursuer_theta,
        pursuer_speed=pursuers[..., 3].copy(),
        pursuer_vel=as_pairs(pursuers[..., 3] * np.exp(1j * pursuer_theta)),
        pursuer_active=np.ones(pursuers.shape[:2], bool),
        evader_xy=evaders[..., :2].copy(),
        evader_theta=evader_theta,
        evader_speed=evaders[..., 3].copy(),
        evader_vel=as_pairs(evaders[..., 3] * np.exp(1j * evader_theta)),
        evader_active=np.ones(evaders.shape[:2], bool),
        obstacle_xy=obstacles[..., :2].copy(),
        obstacle_r=obstacles[..., 2].copy(),
        vortex_xy=vortices[..., :2].copy(),
        vortex_gamma=vortices[..., 2].copy(),
        vortex_clockwise=vortices[..., 3] > 0.5,
        steps=np.zeros(num_envs, np.int64),
    )


Seed = int | np.integer | np.random.Generator | None
"""What seeds a world: an int >= 0; a np.random.Generator, which gives the int (one draw);
None, fresh entropy from the operating system (as NumPy's own default_rng(None))."""


def seed_value(seed: Seed) -> int:
    """The int a `Seed` stands for: the int itself, one draw of a Generator, or fresh
    entropy for None. TypeError names anything else (a float, a string, a bool)."""
    if seed is None:
        return int(np.random.SeedSequence().entropy)
    if isinstance(seed, np.random.Generator):
        return int(seed.integers(2**63))
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)):
        if seed < 0:
            raise ValueError(f"seed must be >= 0, got {seed}")
        return int(seed)
    raise TypeError(
        f"seed must be an int >= 0, a np.random.Generator or None, got {type(seed).__name__} {seed!r:.60}"
    )


class World:
    """B worlds of one scenario. Each owns a random generator spawned from `seed`.

    Environment b draws its episodes from `SeedSequence(seed).spawn(B)[b]`, so a
    `Simulator(scenario, seed)` replays environment 0 of any batch with that seed.
    `seed` is a `Seed`: an int, a np.random.Generator (one draw gives the int) or None
    (fresh entropy); `self.seed` is the int in force. The evaders are the ones the scenario
    names (`Scenario.evader`) unless `evader_policy` gives others.
    """

    def __init__(
        self,
        scenario: Scenario,
        num_envs: int = 1,
        seed: Seed = 0,
        evader_policy: EvaderPolicy | None = None,
    ) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.scenario = scenario
        self.params = scenario.params
        self.num_envs = num_envs
        if evader_policy is not None and not callable(getattr(evader_policy, "act", None)):
            raise TypeError(
                "evader_policy must have an act(state, geometry, params, arena) method (terl_rt.EvaderPolicy) "
                f"or be None, got {type(evader_policy).__name__} {evader_policy!r:.60}"
            )
        self.evader_policy = evader_policy if evader_policy is not None else build_evader(scenario.evader)
        self._seed(seed)
        p, n, m = self.params, scenario.pursuers, scenario.evaders
        self._max_speed = np.concatenate([np.full(n, p.pursuer_max_speed), np.full(m, p.evader_max_speed)])
        self._drag = np.concatenate([np.full(n, p.pursuer_drag), np.full(m, p.evader_drag)])
        self.state: WorldState | None = None
        self.geometry: Geometry | None = None
        self.done = np.ones(num_envs, bool)
        """[B] bool: environments whose episode ended (or never started); reset them."""
        self.episode_return = np.zeros(num_envs)
        """[B] float64: every pursuer's reward summed over the episode so far."""

    def _seed(self, seed: Seed) -> None:
        self.seed = seed_value(seed)
        """the int that seeds the environments' generators now."""
        children = np.random.SeedSequence(self.seed).spawn(self.num_envs)
        self._rngs = [np.random.default_rng(child) for child in children]

    def reseed(self, envs: np.ndarray, seeds: np.ndarray) -> None:
        """Give environments `envs` [K] int the generators that environment 0 of a world
        seeded with `seeds` [K] int has: the next reset of env k starts the episode that
        `Simulator(scenario, seed=seeds[k]).reset()` starts."""
        envs, seeds = np.asarray(envs), np.asarray(seeds)
        if envs.shape != seeds.shape or envs.ndim != 1:
            raise ValueError(f"reseed: envs and seeds must be [K] alike, got shapes {envs.shape} and {seeds.shape}")
        for env, seed in zip(envs.tolist(), seeds.tolist()):
            self._rngs[env] = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])

    def keep(self, envs: np.ndarray) -> None:
        """Keep only environments `envs` [K] int (ascending, K >= 1) and drop the others:
        the batch shrinks to K, environment envs[k] becoming k. What each kept environment
        does next is unchanged, bit for bit."""
        envs = np.asarray(envs)
        if envs.ndim != 1 or envs.size < 1 or envs.dtype.kind not in "iu":
            raise ValueError(f"keep: envs must be [K] int with K >= 1, got {envs.dtype} {envs.shape}")
        if envs[0] < 0 or envs[-1] >= self.num_envs or np.any(np.diff(envs) <= 0):
            raise ValueError(f"keep: envs must be ascending indices in [0, {self.num_envs}), got {envs.tolist()}")
        if self.state is None:
            raise RuntimeError("keep: call reset() first")
        self.state = self.state.take(envs)
        self.geometry = Geometry.of(self.state)  # positions only: the same as the rows kept
        self.done = self.done[envs]
        self.episode_return = self.episode_return[envs]
        self._rngs = [self._rngs[env] for env in envs.tolist()]
        self.num_envs = len(envs)

    # ------------------------------------------------------------------ reset
    def reset(self, env_mask: np.ndarray | None = None, seed: Seed = None) -> Observation:
        """Start new episodes in the environments of `env_mask` ([B] bool; None = all).

        `seed` re-seeds every environment's generator first (only with env_mask None).
        Returns the observations of every pursuer of every environment, [B, N, ...].
        """
        if seed is not None:
            if env_mask is not None:
                raise ValueError("reset: seed re-seeds every environment; pass env_mask=None with it")
            self._seed(seed)
        mask = np.ones(self.num_envs, bool) if env_mask is None else np.array(env_mask, bool)  # a copy: callers pass world.done
        if mask.shape != (self.num_envs,):
            raise ValueError(f"reset: env_mask must have shape ({self.num_envs},), got {mask.shape}")
        if self.state is None and not mask.all():
            raise ValueError("reset: the first reset must start every environment (env_mask=None)")

        init = self.scenario.initial_state
        placements = [
            (init if init is not None else place(self.scenario, self._rngs[b])) if mask[b] else None
            for b in range(self.num_envs)
        ]
        filler = next(pl for pl in placements if pl is not None)
        fresh = _initial_state(self.scenario, [pl if pl is not None else filler for pl in placements])
        if self.state is None:
            self.state = fresh
        else:
            self.state.assign(mask, fresh)
        self.done[mask] = False
        self.episode_return[mask] = 0.0
        self.geometry = Geometry.of(self.state)
        return pursuer_observations(self.state, self.geometry, self.params, self.scenario.evader_slots)

    # ------------------------------------------------------------------ step
    def step(self, pursuer_actions: np.ndarray) -> tuple[Observation, StepResult]:
        """Advance every environment one decision step (0.5 s).

        pursuer_actions [B, N] int in [0, 9) (ignored for inactive pursuers).
        Returns the observations [B, N, ...] after the step and what happened.
        """
        state, geometry, p, scenario = self.state, self.geometry, self.params, self.scenario
        if state is None:
            raise RuntimeError("step: call reset() first")
        if self.done.any():
            raise RuntimeError(
                f"step: the episodes of environments {np.flatnonzero(self.done).tolist()} ended; reset them first"
            )
        actions = _check_actions(pursuer_actions, state.pursuer_active)
        acted = state.pursuer_active.copy()
        evader_was_active = state.evader_active.copy()
        obstacle_before = (
            first_perceived_obstacle_distance(geometry, state.obstacle_r, p) if scenario.reward == "published" else None
        )

        # Evaders decide from the world as it is (geometry cached from the last step).
        evader_actions = _check_actions(
            self.evader_policy.act(state, geometry, p, scenario.arena), evader_was_active,
            f"the evader policy's actions ({type(self.evader_policy).__name__})", NUM_EVADER_ACTIONS,
        )

        # Everyone moves (pursuers and evaders integrated together).
        n = scenario.pursuers
        control = np.concatenate([PURSUER_ACTIONS[actions], EVADER_ACTIONS[evader_actions]], 1)  # [B, N+M, 2]
        xy, theta, speed, velocity = integrate(
            np.concatenate([state.pursuer_xy, state.evader_xy], 1),
            np.concatenate([state.pursuer_theta, state.evader_theta], 1),
            np.concatenate([state.pursuer_speed, state.evader_speed], 1),
            control[..., 0], control[..., 1],
            np.concatenate([acted, evader_was_active], 1),
            self._max_speed, self._drag,
            state.vortex_xy, signed_circulation(state.vortex_gamma, state.vortex_clockwise),
            p.vortex_core_radius, p.dt, p.substeps,
        )
        state.pursuer_xy, state.evader_xy = xy[:, :n], xy[:, n:]
        state.pursuer_theta, state.evader_theta = theta[:, :n], theta[:, n:]
        state.pursuer_speed, state.evader_speed = speed[:, :n], speed[:, n:]
        state.pursuer_vel, state.evader_vel = velocity[:, :n], velocity[:, n:]
        self.geometry = geometry = Geometry.of(state)
        state.pursuer_pursuing = pursuit_status(geometry, p.related_distance)

        # Collisions. A pursuer that collides in this step still counts and is perceived
        # in everything this step computes from here on (world.md section 6).
        collided, touched = collisions(state, geometry, p)
        state.pursuer_touched |= touched
        state.pursuer_active = acted & ~collided
        state.pursuer_perceived = acted

        # The encirclement test: pursuers present in this step test with whom they perceive
        # now; those that collided earlier with whom they perceived last (section 7).
        remember_perceived(state, geometry, p, acted)
        ring = encircle(state, geometry, p, acted)
        if scenario.reward == "published":
            terms, team = published_reward_terms(
                state.pursuer_xy, acted, collided, obstacle_before, geometry, ring, p, scenario.arena,
            )
        else:
            terms, team = paper_reward_terms(
                state.pursuer_xy, acted, state.pursuer_active, collided, evader_was_active,
                state.obstacle_r, geometry, ring, p, scenario.arena,
            )
        state.evader_active = evader_was_active & ~ring.evader_captured
        state.steps += 1

        # Episode end.
        success = ~state.evader_active.any(-1)
        terminated = success | (state.pursuer_active.sum(-1) < p.min_active_pursuers)
        truncated = ~terminated & (state.steps >= scenario.max_steps)
        self.done = terminated | truncated
        reward = terms.sum(-1)
        self.episode_return += reward.sum(-1)

        observation = pursuer_observations(state, geometry, p, scenario.evader_slots)
        return observation, StepResult(
            reward=reward, reward_terms=terms, team_cooperation=team, acted=acted, collided=collided,
            captured=ring.evader_captured, pursuer_target=ring.pursuer_target,
            evader_actions=evader_actions, terminated=terminated, truncated=truncated, success=success,
        )

    def metrics(self, env: int = 0) -> EpisodeMetrics:
        """Metrics of environment `env`'s episode so far."""
        if self.state is None:
            raise RuntimeError("metrics: call reset() first")
        return episode_metrics(self.state, env, self.params, float(self.episode_return[env]))


def _check_actions(
    actions: np.ndarray, active: np.ndarray, name: str = "pursuer_actions", count: int = NUM_PURSUER_ACTIONS,
) -> np.ndarray:
    """Validate action indices [B, N] (or [B, M]) in [0, count), int64; inactive robots'
    entries are ignored. `name` names them in the ValueError."""
    array = np.asarray(actions)
    if array.shape != active.shape:
        raise ValueError(f"{name}: expected shape {active.shape} (one per robot), got {array.shape}")
    if array.dtype.kind not in "iu":
        raise ValueError(f"{name}: expected integer action indices, got dtype {array.dtype}")
    array = np.where(active, array, 0)
    if array.min() < 0 or array.max() >= count:
        bad = array[(array < 0) | (array >= count)]
        raise ValueError(f"{name}: indices must lie in [0, {count}), got {bad[0]} among {array[active].tolist()!s:.200}")
    return array.astype(np.int64, copy=False)
