"""A decentralised shield any policy can wear: each pursuer, from its own observation alone,
predicts where each of its 9 actions takes it and drops the actions that bring it too close
to a teammate, an evader or an obstacle.

The prediction, in the pursuer's ego frame (it starts at the origin, heading 0):

- itself: `terl_rt.sim.dynamics.integrate`, the simulator's own kinematics (world.md
  section 2), from its forward speed, the observed ego vx clipped to [0, s_max]; the
  current, which it does not observe, is left out (docs/safety.md bounds what that costs).
  The first decision step holds the action; every later one of the horizon holds the
  fallback manoeuvre: the same yaw rate (keep swerving) at the lowest acceleration (brake);
- teammates and evaders at their observed ground velocities, obstacles still, each
  robot a disc of the robot radius, an obstacle of its observed radius.

Clearance is the centre distance less both radii (world.md section 6: <= 0 is a
collision). Between decision steps the relative motion is taken as straight, and its
closest approach counted, so nothing passes unseen between two predicted points. An
action is kept when, for every entity seen, its predicted clearance stays at least the
margin, or, for an entity already inside the margin, at least the clearance it has now
(the shield never forbids moving away). Among the kept actions the policy's own choice
stands; when the shield drops it, the kept action the policy prefers next (highest value;
for a policy that gives only an action, the kept action of largest clearance); when none
is kept, the action of largest clearance.

Letters: R decision rows (pursuers), A = 9 actions, H the horizon in decision steps,
S = P + E + O entity slots.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from terl_rt.sim.actions import NUM_PURSUER_ACTIONS, PURSUER_ACCELERATIONS, PURSUER_ACTIONS
from terl_rt.sim.dynamics import as_complex, integrate
from terl_rt.sim.observation import Observation
from terl_rt.sim.params import WorldParams

DEFAULT_MARGIN_M = 0.5
"""m: the clearance an action must keep (docs/safety.md, "Why these defaults")."""
DEFAULT_HORIZON_STEPS = 4
"""decision steps (0.5 s each) predicted: the action's, then the fallback's (docs/safety.md)."""
MAX_MARGIN_M = 10.0
"""m: the largest margin (a wider one forbids every ring: encircling is within 8 m)."""
MAX_HORIZON_STEPS = 20
"""decision steps: the longest horizon (10 s; constant-velocity guesses mean nothing beyond)."""


@dataclass(frozen=True)
class Shield:
    """The shield's parameters."""

    margin_m: float = DEFAULT_MARGIN_M
    """m: the predicted clearance an action must keep, in [0, MAX_MARGIN_M]."""
    horizon_steps: int = DEFAULT_HORIZON_STEPS
    """decision steps predicted, in [1, MAX_HORIZON_STEPS]: the action's, then the fallback's."""

    def __post_init__(self) -> None:
        margin, horizon = self.margin_m, self.horizon_steps
        if isinstance(margin, bool) or not isinstance(margin, (int, float)) or not 0 <= margin <= MAX_MARGIN_M:
            raise ValueError(f"shield margin must be a number of m in [0, {MAX_MARGIN_M:g}], got {margin!r:.40}")
        if isinstance(horizon, bool) or not isinstance(horizon, int) or not 1 <= horizon <= MAX_HORIZON_STEPS:
            raise ValueError(f"shield horizon must be an integer of decision steps in [1, {MAX_HORIZON_STEPS}], "
                             f"got {horizon!r:.40}")

    @property
    def label(self) -> str:
        """e.g. "shield 0.5 m / 4 steps", as results name a shielded row."""
        return f"shield {self.margin_m:g} m / {self.horizon_steps} steps"

    def to_dict(self) -> dict:
        return asdict(self)


def own_paths(forward_speed: np.ndarray, params: WorldParams, horizon_steps: int) -> np.ndarray:
    """[R, A, H + 1] complex m: the ego-frame position of a pursuer at the end of each decision
    step (0 first) for each first action, from forward_speed [R] m/s at the origin, heading 0;
    world.md section 2 without the current, the fallback manoeuvre after the first step."""
    rows = len(forward_speed)
    shape = (rows, NUM_PURSUER_ACTIONS)
    xy = np.zeros(shape + (2,))
    theta = np.zeros(shape)
    speed = np.broadcast_to(forward_speed[:, None], shape).astype(np.float64)
    acceleration = np.broadcast_to(PURSUER_ACTIONS[:, 0], shape)
    yaw_rate = np.broadcast_to(PURSUER_ACTIONS[:, 1], shape)
    brake = np.full(shape, PURSUER_ACCELERATIONS.min())
    moving = np.ones(shape, bool)
    max_speed = np.full(NUM_PURSUER_ACTIONS, params.pursuer_max_speed)
    drag = np.full(NUM_PURSUER_ACTIONS, params.pursuer_drag)
    no_cores, no_circulation = np.zeros((rows, 0, 2)), np.zeros((rows, 0))
    points = np.zeros(shape + (horizon_steps + 1,), np.complex128)
    for step in range(horizon_steps):
        xy, theta, speed, _ = integrate(
            xy, theta, speed, acceleration if step == 0 else brake, yaw_rate, moving, max_speed, drag,
            no_cores, no_circulation, params.vortex_core_radius, params.dt, params.substeps,
        )
        points[..., step + 1] = as_complex(xy)
    return points


def _entities(observation: Observation, params: WorldParams) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every slot's ego-frame position [R, S] complex m, velocity [R, S] complex m/s, radius
    [R, S] m and presence [R, S] bool: teammates, evaders, obstacles (still), in mask order."""
    movers = np.concatenate([observation.teammates, observation.evaders], axis=1).astype(np.float64)
    obstacles = observation.obstacles.astype(np.float64)
    position = np.concatenate([movers[..., 0] + 1j * movers[..., 1], obstacles[..., 0] + 1j * obstacles[..., 1]], 1)
    velocity = np.concatenate([movers[..., 2] + 1j * movers[..., 3], np.zeros(obstacles.shape[:2])], 1)
    radius = np.concatenate([np.full(movers.shape[:2], params.robot_radius), obstacles[..., 2]], 1)
    return position, velocity, radius, observation.mask[:, 1:]


def safety_scores(observation: Observation, params: WorldParams, shield: Shield) -> np.ndarray:
    """[R, A] m: for each row of `observation` (leading shape [R]) and each first action, the
    least, over the entities seen that could come within the margin in the horizon, of the
    predicted clearance less what it must keep (the margin, or the present clearance when
    that is smaller); the action is kept when >= 0. +inf for a pursuer near nothing."""
    horizon = shield.horizon_steps
    rows = len(observation.ego)
    times = np.arange(horizon + 1) * (params.dt * params.substeps)  # s, [H + 1]
    position, velocity, radius, present = _entities(observation, params)
    reach = params.robot_radius + radius  # [R, S] m: centre distance of contact
    distance = np.abs(position)
    keep = np.minimum(shield.margin_m, distance - reach)  # [R, S] m
    # Only entities that could come within `keep` count: neither moves faster than its speed
    # (the pursuer: s_max) for the horizon. The rest cannot make an action unsafe; leaving
    # them out spares most of the work (far evaders fill most slots).
    travel = (params.pursuer_max_speed + np.abs(velocity)) * times[-1]
    row, slot = np.nonzero(present & (distance - travel - reach < keep))
    scores = np.full((rows, NUM_PURSUER_ACTIONS), np.inf)
    if not len(row):
        return scores
    # The pairs come row by row (np.nonzero's order): `first` starts each row's run.
    first = np.flatnonzero(np.r_[True, row[1:] != row[:-1]])
    deciding = row[first]  # the rows with a close pair, ascending
    forward = np.clip(observation.ego[deciding, 0].astype(np.float64), 0.0, params.pursuer_max_speed)
    pairs_of = np.diff(np.r_[first, len(row)])  # pairs of each deciding row
    own = np.repeat(own_paths(forward, params, horizon), pairs_of, axis=0)  # [K, A, H + 1] for the K pairs
    others = position[row, slot, None] + velocity[row, slot, None] * times  # [K, H + 1]
    relative = others[:, None] - own  # [K, A, H + 1]
    start, change = relative[..., :-1], np.diff(relative, axis=-1)  # each decision step as a segment
    # The closest approach on each segment: u* = -Re(start conj(change)) / |change|^2 in [0, 1].
    squared = (change * change.conj()).real
    along = -(start * change.conj()).real
    u = np.clip(np.divide(along, squared, out=np.zeros_like(along), where=squared > 0), 0.0, 1.0)
    closest = np.abs(start + u * change).min(axis=-1)  # [K, A] m
    pair_scores = closest - (reach[row, slot] + keep[row, slot])[:, None]
    scores[deciding] = np.minimum.reduceat(pair_scores, first, axis=0)  # the least of each row's pairs
    return scores


def shielded_actions(actions: np.ndarray, preference: np.ndarray | None, scores: np.ndarray) -> np.ndarray:
    """[R] int64: the shield's choice from the policy's actions [R], its preference [R, A]
    (higher first: Q-values or their risk-aware form; None for a policy of actions alone) and
    the `safety_scores` [R, A]. An action kept (score >= 0) stands; else the kept action of
    highest preference, ties and a policy without one to the largest score; none kept, the
    action of largest score."""
    rows = np.arange(len(actions))
    kept = scores >= 0.0
    by_clearance = np.where(kept, scores, -np.inf)
    if preference is not None:
        best = np.where(kept, preference, -np.inf).max(axis=-1, initial=-np.inf)
        by_clearance = np.where(kept & (preference == best[:, None]), scores, -np.inf)
    fallback = np.where(kept.any(axis=-1), by_clearance.argmax(axis=-1), scores.argmax(axis=-1))
    return np.where(kept[rows, actions], actions, fallback).astype(np.int64)


def shield_actions(
    observation: Observation, actions: np.ndarray, preference: np.ndarray | None, params: WorldParams, shield: Shield,
) -> tuple[np.ndarray, np.ndarray]:
    """The shield on the R rows of `observation`: (actions [R] int64, overridden [R] bool)
    from the policy's actions [R] and preference [R, A] or None (`shielded_actions`)."""
    actions = np.asarray(actions, np.int64)
    chosen = shielded_actions(actions, preference, safety_scores(observation, params, shield))
    return chosen, chosen != actions

