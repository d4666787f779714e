"""A user's script, type-checked against the installed terl-rt (mypy reads py.typed)."""

import numpy as np

from terl_rt import Scenario, Simulator

scenario: Scenario = Scenario.preset("small-15")
sim = Simulator(scenario, seed=np.random.default_rng(0))
sim.reset()
pursuers: int = scenario.pursuers
done: bool = sim.done
