"""Run a policy inside your own controller: from what one robot knows to its next action.

`decide` takes one pursuer's view of the world in world coordinates (m, rad, m/s),
builds its observation exactly as the simulator does (terl_rt.sim.observation on a
one-environment world with this robot as pursuer 0) and asks the policy. `observe`
stops before the policy, for those who run their own model.

Example (hold the returned acceleration and yaw rate for one 0.5 s decision step)::

    import numpy as np
    from terl_rt.policy.embed import decide
    from terl_rt.policy.onnx_policy import OnnxPolicy

    policy = OnnxPolicy("exported/terl.onnx")
    decision = decide(
        policy,
        ego_xy=(10.0, 12.0), ego_heading=0.3, ego_velocity=(1.2, 0.4),
        teammates=[(18.0, 15.0, 0.5, 1.0), (4.0, 20.0, -0.2, 0.8)],  # x, y, vx, vy
        evaders=[(30.0, 25.0, -1.0, 0.0)],                           # x, y, vx, vy
        obstacles=[(15.0, 5.0, 1.05)],                               # x, y, radius
    )
    print(decision.action, decision.acceleration, decision.yaw_rate)
    print(np.round(decision.q_values, 3), decision.target_weights)

`decide(..., shield=True)` puts the choice under the shield and `risk="cvar:0.25"` acts on
the CVaR of the policy's quantiles (terl_rt.safety, docs/safety.md);
`decision.overridden` says whether the shield replaced the policy's action.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from terl_rt.policy.contract import ContractError
from terl_rt.safety.acting import Acting
from terl_rt.safety.risk import Risk
from terl_rt.safety.shield import Shield
from terl_rt.sim.actions import PURSUER_ACTIONS
from terl_rt.sim.geometry import Geometry
from terl_rt.sim.observation import Observation, pursuer_observations, pursuit_status
from terl_rt.sim.params import WorldParams, check_params
from terl_rt.sim.state import WorldState


@dataclass(frozen=True)
class Decision:
    """What the policy chose for one pursuer."""

    action: int
    """index into the pursuer action table (world.md section 2)."""
    acceleration: float
    """m/s^2: linear acceleration to hold for one decision step (0.5 s)."""
    yaw_rate: float
    """rad/s: yaw rate to hold for one decision step."""
    q_values: np.ndarray
    """[9] float32: expected return of each action."""
    target_weights: np.ndarray | None
    """[E] float32 preference over the evader slots (nearest first), or None when the
    model has no target selection."""
    overridden: bool = False
    """the shield replaced the action the policy chose (always False without a shield)."""


MAX_ROWS = {"teammates": 1000, "evaders": 500, "obstacles": 500, "encircled": 500}
"""Most rows `observe` takes per argument (the scenario limits): memory grows with the
square of the entities, so larger inputs are refused with a ValueError."""
MAX_EVADER_SLOTS = 256
"""Largest evader_slots."""
MAX_COORDINATE = 1e6
"""m: largest |x| or |y| of any position."""
MAX_SPEED = 1e3
"""m/s: largest |vx| or |vy| of any velocity."""
MAX_RADIUS = 100.0
"""m: largest obstacle radius."""


def _bounded(name: str, array: np.ndarray, columns: str, bounds: tuple[float, ...]) -> None:
    """ValueError naming `name`, the row and the column of the first value beyond its bound."""
    if array.size == 0:
        return
    over = np.abs(array) > np.asarray(bounds)[None, :]
    if over.any():
        row, col = (int(i) for i in np.argwhere(over)[0])
        raise ValueError(
            f"{name}[{row}]: {columns.split(', ')[col]} is {array[row, col]:g}; it must lie within +-{bounds[col]:g}"
        )


def _rows(name: str, value, width: int, columns: str) -> np.ndarray:
    """A [K, width] float64 array from rows; ValueError naming `name` when malformed."""
    limit = MAX_ROWS[name]
    if value is not None and hasattr(value, "__len__") and len(value) > limit:
        raise ValueError(f"{name}: {len(value)} rows, more than the {limit} observe takes (MAX_ROWS)")
    try:
        array = np.asarray(value if value is not None else [], dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name}: expected rows of {width} numbers ({columns}), got {_short(value)}") from None
    if array.size == 0:
        array = array.reshape(0, width)
    if array.ndim != 2 or array.shape[1] != width:
        raise ValueError(f"{name}: expected shape (K, {width}) of rows ({columns}), got {array.shape}")
    bad = ~np.isfinite(array)
    if bad.any():
        row, col = (int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"{name}[{row}]: {columns.split(', ')[col]} is {array[row, col]}; every value must be finite")
    if len(array) > limit:
        raise ValueError(f"{name}: {len(array)} rows, more than the {limit} observe takes (MAX_ROWS)")
    return array


def _short(value) -> str:
    text = repr(value) if not isinstance(value, np.ndarray) else f"an array of shape {value.shape}"
    return text if len(text) <= 60 else text[:57] + "..."


def _vector(name: str, value, size: int, columns: str) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name}: expected {size} numbers ({columns}), got {_short(value)}") from None
    if array.shape != (size,):
        raise ValueError(f"{name}: expected shape ({size},) ({columns}), got {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name}: {array.tolist()} holds a non-finite value; every value must be finite")
    return array


def observe(
    ego_xy,
    ego_heading: float,
    ego_velocity,
    teammates=None,
    evaders=None,
    obstacles=None,
    evader_slots: int = 8,
    params: WorldParams | None = None,
    encircled=None,
) -> Observation:
    """The observation of one pursuer, leading shape [1] (pursuer_index [0]).

    ego_xy (2,) m; ego_heading rad; ego_velocity (2,) m/s ground velocity (steer plus
    current), world frame. teammates [T, 4] (x, y, vx, vy) of the other active pursuers,
    evaders [M, 4] (x, y, vx, vy) of the evaders not yet encircled, obstacles [O, 3]
    (x, y, radius): world frame, any number of rows, in any order; perception (radius R)
    and slot limits apply as in the simulator. evader_slots: E, the policy's evader
    slots (8 small, 14 medium, 20 large, 12 CC). params: the world's constants
    (perception radius, robot radius, ...), default WorldParams(). encircled [K, 2]
    (x, y) of the evaders already encircled: nobody observes them, but as in the
    published simulator they still set the pursuit status (an evader within 18 m).
    Raises ValueError naming the argument for wrong shapes, non-finite values, values
    out of bounds (positions within +-MAX_COORDINATE m, velocities within +-MAX_SPEED m/s,
    radii in (0, MAX_RADIUS]), too many rows (MAX_ROWS), evader_slots outside
    [1, MAX_EVADER_SLOTS] or params outside their ranges (terl_rt.sim.params.PARAM_RANGES).
    """
    params = WorldParams() if params is None else params
    if not isinstance(params, WorldParams):
        raise ValueError(f"params: expected a WorldParams or None, got {type(params).__name__}")
    problem = check_params(params)
    if problem:
        raise ValueError(f"params.{problem[0]}: {problem[1]}")
    if (isinstance(evader_slots, bool) or not isinstance(evader_slots, (int, np.integer))
            or not 1 <= evader_slots <= MAX_EVADER_SLOTS):
        raise ValueError(f"evader_slots: expected an integer in [1, {MAX_EVADER_SLOTS}], got {_short(evader_slots)}")
    xy = _vector("ego_xy", ego_xy, 2, "x, y")
    velocity = _vector("ego_velocity", ego_velocity, 2, "vx, vy")
    try:
        if isinstance(ego_heading, (str, bytes, bool, np.bool_)):
            raise TypeError  # float("3") would pass: a heading is a number
        heading = float(ego_heading)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"ego_heading: expected one number (rad), got {_short(ego_heading)}") from None
    if not math.isfinite(heading) or abs(heading) > MAX_COORDINATE:
        raise ValueError(f"ego_heading: is {heading:g}; it must be finite, within +-{MAX_COORDINATE:g} rad")
    mates = _rows("teammates", teammates, 4, "x, y, vx, vy")
    targets = _rows("evaders", evaders, 4, "x, y, vx, vy")
    discs = _rows("obstacles", obstacles, 3, "x, y, radius")
    done = _rows("encircled", encircled, 2, "x, y")
    if (discs[:, 2] <= 0).any():
        row = int(np.flatnonzero(discs[:, 2] <= 0)[0])
        raise ValueError(f"obstacles[{row}]: radius is {discs[row, 2]}; radii must be > 0")
    _bounded("ego_xy", xy[None], "x, y", (MAX_COORDINATE, MAX_COORDINATE))
    _bounded("ego_velocity", velocity[None], "vx, vy", (MAX_SPEED, MAX_SPEED))
    _bounded("teammates", mates, "x, y, vx, vy", (MAX_COORDINATE, MAX_COORDINATE, MAX_SPEED, MAX_SPEED))
    _bounded("evaders", targets, "x, y, vx, vy", (MAX_COORDINATE, MAX_COORDINATE, MAX_SPEED, MAX_SPEED))
    _bounded("obstacles", discs, "x, y, radius", (MAX_COORDINATE, MAX_COORDINATE, MAX_RADIUS))
    _bounded("encircled", done, "x, y", (MAX_COORDINATE, MAX_COORDINATE))

    # One world, the ego as pursuer 0. Teammates' and evaders' headings follow their
    # velocity; the observation reads only the observer's heading.
    pursuer_xy = np.concatenate([xy[None], mates[:, :2]])
    pursuer_vel = np.concatenate([velocity[None], mates[:, 2:]])
    pursuer_theta = np.concatenate([[heading], np.arctan2(mates[:, 3], mates[:, 2])]) % (2 * math.pi)
    evader_theta = np.arctan2(targets[:, 3], targets[:, 2]) % (2 * math.pi)
    # Encircled evaders ride along inactive, at rest.
    targets = np.concatenate([targets, np.column_stack([done, np.zeros_like(done)])])
    evader_theta = np.concatenate([evader_theta, np.zeros(len(done))])
    evader_active = np.arange(len(targets)) < len(targets) - len(done)
    state = WorldState(
        pursuer_xy=pursuer_xy[None],
        pursuer_theta=pursuer_theta[None],
        pursuer_speed=np.hypot(pursuer_vel[:, 0], pursuer_vel[:, 1])[None],
        pursuer_vel=pursuer_vel[None],
        pursuer_active=np.ones((1, len(pursuer_xy)), bool),
        evader_xy=targets[None, :, :2].copy(),
        evader_theta=evader_theta[None],
        evader_speed=np.hypot(targets[:, 2], targets[:, 3])[None],
        evader_vel=targets[None, :, 2:].copy(),
        evader_active=evader_active[None],
        obstacle_xy=discs[None, :, :2].copy(),
        obstacle_r=discs[None, :, 2].copy(),
        vortex_xy=np.zeros((1, 0, 2)),
        vortex_gamma=np.zeros((1, 0)),
        vortex_clockwise=np.zeros((1, 0), bool),
        steps=np.zeros(1, np.int64),
    )
    geometry = Geometry.of(state)
    state.pursuer_pursuing = pursuit_status(geometry, params.related_distance)
    every = pursuer_observations(state, geometry, params, int(evader_slots))
    return Observation(
        ego=every.ego[0, :1],
        teammates=every.teammates[0, :1],
        evaders=every.evaders[0, :1],
        obstacles=every.obstacles[0, :1],
        mask=every.mask[0, :1],
        pursuer_index=np.zeros(1, np.int64),
    )


def decide(
    policy,
    ego_xy,
    ego_heading: float,
    ego_velocity,
    teammates=None,
    evaders=None,
    obstacles=None,
    evader_slots: int = 8,
    params: WorldParams | None = None,
    encircled=None,
    shield: Shield | bool | None = None,
    risk: Risk | str | None = None,
) -> Decision:
    """The policy's action for one pursuer; arguments as in `observe`.

    policy: an `OnnxPolicy` (anything with its `evaluate`). Open it once and reuse it.
    shield: True (the default `Shield`) or a Shield: the shield chooses among the actions
    it keeps (terl_rt.safety.shield). risk: "cvar:ALPHA" or a Risk: act on the CVaR of the
    policy's quantiles (ValueError for a policy without them).
    Raises TypeError for anything else as `policy` (a path among them), ContractError (a
    ValueError) when the policy outputs NaN or Inf, as `terl-rt eval` does, or fails
    inside onnxruntime (`PolicyRunError`).
    """
    if not callable(getattr(policy, "evaluate", None)):
        raise TypeError(
            "policy must be an opened policy such as OnnxPolicy(path), opened once and reused, "
            f"got {type(policy).__name__} {policy!r:.60}"
        )
    acting = Acting.of(shield, risk)
    acting.check(policy)
    observation = observe(
        ego_xy, ego_heading, ego_velocity, teammates, evaders, obstacles, evader_slots, params, encircled
    )
    output = acting.act(policy, observation, WorldParams() if params is None else params)
    problem = output.first_non_finite()
    if problem is not None:
        name, _, bad = problem
        raise ContractError(
            f"policy {getattr(policy, 'name', policy)} output a non-finite {name} ({bad}); "
            "no action can be chosen from it"
        )
    action = int(output.actions[0])
    acceleration, yaw_rate = PURSUER_ACTIONS[action]
    return Decision(
        action=action,
        acceleration=float(acceleration),
        yaw_rate=float(yaw_rate),
        q_values=output.q_values[0],
        target_weights=None if output.target_weights is None else output.target_weights[0],
        overridden=output.overridden is not None and bool(output.overridden[0]),
    )
