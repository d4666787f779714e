"""Robot kinematics and vortex currents (world.md sections 2-3), pure functions over arrays.

Letters: B environments, R robots (pursuers and evaders together), V vortex cores.
"""

from __future__ import annotations

import numpy as np

TWO_PI = 2.0 * np.pi


def signed_circulation(gamma: np.ndarray, clockwise: np.ndarray) -> np.ndarray:
    """Gamma / (2 pi), positive for clockwise cores: [B, V] m^2/s in, [B, V] out."""
    return np.where(clockwise, gamma, -gamma) / TWO_PI


def as_complex(xy: np.ndarray) -> np.ndarray:
    """View points [..., 2] (float64, last axis contiguous) as complex x + iy [...], no copy."""
    return xy.view(np.complex128)[..., 0]


def as_pairs(z: np.ndarray) -> np.ndarray:
    """View complex points [...] as float64 pairs [..., 2], no copy."""
    return np.ascontiguousarray(z)[..., None].view(np.float64)


def vortex_current(z: np.ndarray, core_z: np.ndarray, circulation: np.ndarray, core_radius: float) -> np.ndarray:
    """Sum of the Rankine vortex currents at points, complex (vx + i vy).

    z [B, R] complex m; core_z [B, V] complex m; circulation [B, V] from
    `signed_circulation`; returns [B, R] complex m/s.

    With `u` the unit vector from the point to the core at distance d, a core adds
    `speed * Rot u`, speed = Gamma d / (2 pi r0^2) inside the core and
    Gamma / (2 pi d) beyond. So speed * u = Gamma / (2 pi max(d^2, r0^2)) * (core - x)
    needs no square root, and Rot = [[0, -1], [1, 0]] (clockwise) is a product
    with i; the opposite rotation is folded into the sign of `circulation`.
    """
    return _CurrentSum(z, core_z, core_radius)((1j * circulation)[:, None, :])


def integrate(
    xy: np.ndarray,
    theta: np.ndarray,
    speed: np.ndarray,
    acceleration: np.ndarray,
    yaw_rate: np.ndarray,
    moving: np.ndarray,
    max_speed: np.ndarray,
    drag: np.ndarray,
    core_xy: np.ndarray,
    circulation: np.ndarray,
    core_radius: float,
    dt: float,
    substeps: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One decision step of `substeps` integration sub-steps of `dt` s (world.md section 2).

    xy [B, R, 2] m; theta [B, R] rad; speed [B, R] m/s; acceleration [B, R] m/s^2 and
    yaw_rate [B, R] rad/s held for the step; moving [B, R] bool (others stay put with
    zero velocity); max_speed, drag [R] (m/s, 1/s); core_xy [B, V, 2] m and
    circulation [B, V] as in `vortex_current`.
    Returns new (xy [B, R, 2], theta [B, R], speed [B, R], velocity [B, R, 2] m/s of
    the last sub-step, world frame).

    Each sub-step: c = current(x); v = s (cos theta, sin theta) + c; x += v dt;
    s = clip(s + (a - k s) dt, 0, s_max); theta = (theta + w dt) mod 2pi.
    Heading and speed do not depend on position: they are computed for every
    sub-step j first, and only the position update loops with the current. The
    heading in closed form, theta_j = (theta + j w dt) mod 2pi. The speed map
    s -> s + (a - k s) dt is affine with fixed point s* = a / k <= s_max; while
    k dt <= 1 it is increasing, the clip binds monotonically and the iterated clip
    equals clip(s* + (s - s*) (1 - k dt)^j, 0, s_max); otherwise it is iterated.
    """
    count = np.arange(substeps + 1)[:, None, None]  # sub-step index j, [S+1, 1, 1]
    turned = theta + count[:substeps] * (yaw_rate * dt)  # [S, B, R] rad, unwrapped (only cos, sin are taken)
    final_theta = np.mod(theta + substeps * (yaw_rate * dt), TWO_PI)
    final_theta[final_theta >= TWO_PI] = 0.0  # mod of a tiny negative angle rounds to 2pi
    if drag.max(initial=0.0) * dt <= 1.0:
        terminal = acceleration / drag  # s*, [B, R]
        speeds = np.minimum(np.maximum(terminal + (speed - terminal) * (1.0 - drag * dt) ** count, 0.0), max_speed)
    else:
        speeds = np.empty((substeps + 1,) + speed.shape)  # [S+1, B, R]
        speeds[0] = speed
        for j in range(substeps):
            s = speeds[j]
            speeds[j + 1] = np.minimum(np.maximum(s + (acceleration - drag * s) * dt, 0.0), max_speed)
    steer = speeds[:substeps] * np.exp(1j * turned)  # [S, B, R] complex m/s
    step_scale = moving * dt  # [B, R]: 0 freezes a robot

    z = as_complex(xy).copy()  # [B, R] complex m, advanced in place
    drift = steer * step_scale  # [S, B, R] complex m: the steer part of each sub-step's move
    if core_xy.shape[1] > 0:
        # The current's part of a move, folded into one weight per (robot, core):
        # dt * i * circulation, times (core - x) / max(d^2, r0^2) as in vortex_current.
        currents = _CurrentSum(z, as_complex(core_xy), core_radius)
        spin = (1j * circulation)[:, None, :]  # [B, 1, V]: i * circulation, the current's weight
        weight = spin * step_scale[:, :, None]  # [B, R, V]
        for k in range(substeps - 1):
            z += currents(weight)  # the current at the sub-step's starting point
            z += drift[k]
        velocity = steer[-1] + currents(spin)  # vortex_current at z
    else:
        z += drift[:-1].sum(axis=0)
        velocity = steer[-1]
    z += velocity * step_scale

    if moving.all():
        return as_pairs(z), final_theta, speeds[-1], as_pairs(velocity)
    velocity[~moving] = 0.0
    return as_pairs(z), np.where(moving, final_theta, theta), np.where(moving, speeds[-1], speed), as_pairs(velocity)


class _CurrentSum:
    """sum over cores of weight * (core - z) / max(|core - z|^2, r0^2) at the points z,
    which the caller moves in place between calls: [B, R] complex for weights [B, R or 1, V].

    The buffers are reused and every array is complex (d^2 as diff * conj(diff)):
    at the sizes of a world, NumPy's per-call and mixed real/complex costs dominate.
    """

    def __init__(self, z: np.ndarray, core_z: np.ndarray, core_radius: float) -> None:
        self.z_column = z[:, :, None]  # [B, R, 1], a view of the caller's points
        self.core_row = core_z[:, None, :]  # [B, 1, V]
        self.floor = complex(core_radius * core_radius)
        shape = (z.shape[0], z.shape[1], core_z.shape[1])
        self.diff, self.scaled = np.empty(shape, np.complex128), np.empty(shape, np.complex128)
        self.total = np.empty(z.shape, np.complex128)

    def __call__(self, weight: np.ndarray) -> np.ndarray:
        diff, scaled = self.diff, self.scaled
        np.subtract(self.core_row, self.z_column, out=diff)
        np.conjugate(diff, out=scaled)
        np.multiply(scaled, diff, out=scaled)  # d^2 + 0i
        np.maximum(scaled, self.floor, out=scaled)
        np.divide(weight, scaled, out=scaled)
        np.multiply(scaled, diff, out=scaled)
        return np.add.reduce(scaled, axis=2, out=self.total)
