"""terl-rt: the TERL encirclement world, its policies and tools, without torch."""

from terl_rt.evader import ConstantEvader, EvaderPolicy, PublishedAPFEvader
from terl_rt.metrics import EpisodeMetrics
from terl_rt.observation import Observation
from terl_rt.params import WorldParams
from terl_rt.scenario import PAPER_SUITE, Scenario, ScenarioError
from terl_rt.simulator import Simulator, StepInfo
from terl_rt.world import StepResult, World

__all__ = [
    "ConstantEvader", "EpisodeMetrics", "EvaderPolicy", "Observation", "PAPER_SUITE",
    "PublishedAPFEvader", "Scenario", "ScenarioError", "Simulator", "StepInfo",
    "StepResult", "World", "WorldParams",
]
