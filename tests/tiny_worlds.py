"""Small hand-placed scenarios for the runtime's tests (evaluation, logs, replay, render).

`capture_scenario()` is built so that the first step has both kinds of event:
three pursuers stand round evader 0 at 5 m, 120 degrees apart (within d_encircle = 8,
gaps 2pi/3 <= pi and max/min gap 1 <= kappa = 3: encircled after one step), and
pursuers 3 and 4 start 2.5 m apart (just over two robot radii, 2.24 m) driving
head-on at 2 m/s, so they collide in step 1 whatever they do. Pursuers 5 and 6 and evader 1 are far off, so the episode
goes on (5 active pursuers >= 3) until its step limit.
"""

from __future__ import annotations

import math

from terl_rt.sim.scenario import Scenario


def capture_scenario(max_steps: int = 12) -> Scenario:
    ring = [
        [60.0 + 5.0 * math.cos(a), 60.0 + 5.0 * math.sin(a), a + math.pi, 0.0]
        for a in (0.0, 2 * math.pi / 3, 4 * math.pi / 3)
    ]
    return Scenario.from_dict({
        "name": "tiny-capture",
        "arena": [120.0, 120.0],
        "evader_slots": 4,
        "max_steps": max_steps,
        "initial_state": {
            "pursuers": ring + [
                [20.0, 20.0, 0.0, 2.0],
                [22.5, 20.0, math.pi, 2.0],
                [100.0, 20.0, 1.0, 1.0],
                [20.0, 100.0, 2.0, 1.5],
            ],
            "evaders": [[60.0, 60.0, 0.0, 0.0], [100.0, 100.0, 3.0, 2.0]],
            "obstacles": [[40.0, 90.0, 1.05]],
            "vortices": [[85.0, 45.0, 4.0, True], [30.0, 60.0, 6.0, False]],
        },
    })
