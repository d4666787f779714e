"""terl-rt: the TERL encirclement world, its policies and tools, without torch."""

__version__ = "0.1.0"
"""The package version (pyproject.toml reads it from here)."""

from typing import TYPE_CHECKING

from terl_rt.sim.evader import ConstantEvader, EvaderPolicy, PublishedAPFEvader
from terl_rt.sim.metrics import EpisodeMetrics
from terl_rt.sim.observation import Observation
from terl_rt.sim.params import WorldParams
from terl_rt.sim.scenario import PAPER_SUITE, Scenario, ScenarioError
from terl_rt.sim.simulator import Simulator, StepInfo
from terl_rt.sim.world import StepResult, World

if TYPE_CHECKING:
    from terl_rt.evaluation.evaluate import Evaluation, evaluate

__all__ = [
    "ConstantEvader", "EpisodeMetrics", "EvaderPolicy", "Evaluation", "Observation", "PAPER_SUITE",
    "PublishedAPFEvader", "Scenario", "ScenarioError", "Simulator", "StepInfo",
    "StepResult", "World", "WorldParams", "__version__", "evaluate",
]

_EVALUATION = ("Evaluation", "evaluate")
"""Names of terl_rt.evaluation.evaluate that `terl_rt` gives, imported when first asked for:
`import terl_rt` loads the simulator with NumPy alone (onnxruntime and mcap wait)."""


def __getattr__(name: str):
    if name in _EVALUATION:
        from terl_rt.evaluation import evaluate as module

        return getattr(module, name)
    raise AttributeError(f"module 'terl_rt' has no attribute {name!r}")
