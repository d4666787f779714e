"""terl-rt: the TERL encirclement world, its policies and tools, without torch."""

__version__ = "0.1.0"
"""The package version (pyproject.toml reads it from here)."""

from terl_rt.sim.evader import ConstantEvader, EvaderPolicy, PublishedAPFEvader
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.observation import Observation
from terl_rt.sim.params import WorldParams
from terl_rt.sim.scenario import PAPER_SUITE, Scenario, ScenarioError
from terl_rt.sim.simulator import Simulator, StepInfo
from terl_rt.sim.world import StepResult, World

__all__ = [
    "ConstantEvader", "EpisodeMetrics", "EvaderPolicy", "Observation", "PAPER_SUITE",
    "PublishedAPFEvader", "Scenario", "ScenarioError", "Simulator", "StepInfo",
    "StepResult", "World", "WorldParams", "__version__",
]
