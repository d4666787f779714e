"""Discrete action tables of pursuers and evaders (world.md section 2).

An action is a pair (linear acceleration in m/s^2, yaw rate in rad/s) held for
one decision step. Tables are the Cartesian product of the acceleration set and
the yaw-rate set, acceleration major: index = i_a * len(yaw_rates) + i_w.
"""

from __future__ import annotations

import numpy as np

PURSUER_ACCELERATIONS = np.array([-0.4, 0.0, 0.4])
"""Pursuer acceleration set a_set, m/s^2."""
PURSUER_YAW_RATES = np.array([-np.pi / 6, 0.0, np.pi / 6])
"""Pursuer yaw-rate set w_set, rad/s."""
EVADER_ACCELERATIONS = np.array([-0.4, 0.0, 0.4])
"""Evader acceleration set a_set, m/s^2."""
EVADER_YAW_RATES = np.array([-np.pi / 6, -np.pi / 12, 0.0, np.pi / 12, np.pi / 6])
"""Evader yaw-rate set w_set, rad/s."""


def action_table(accelerations: np.ndarray, yaw_rates: np.ndarray) -> np.ndarray:
    """Cartesian product, acceleration major: [len(a) * len(w), 2] of (m/s^2, rad/s)."""
    accel, yaw = np.meshgrid(accelerations, yaw_rates, indexing="ij")
    return np.stack([accel.ravel(), yaw.ravel()], axis=-1)


PURSUER_ACTIONS = action_table(PURSUER_ACCELERATIONS, PURSUER_YAW_RATES)
"""[9, 2] pursuer action table: row i is (acceleration m/s^2, yaw rate rad/s)."""
EVADER_ACTIONS = action_table(EVADER_ACCELERATIONS, EVADER_YAW_RATES)
"""[15, 2] evader action table: row i is (acceleration m/s^2, yaw rate rad/s)."""
NUM_PURSUER_ACTIONS = len(PURSUER_ACTIONS)
NUM_EVADER_ACTIONS = len(EVADER_ACTIONS)
