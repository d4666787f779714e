"""terl-rt: the TERL encirclement world, its policies and tools, without torch.

The names below load on first use (PEP 562), so that `import terl_rt` (and with it the
`terl-rt` command's entry point) imports nothing that Ctrl-C or a memory limit could
interrupt before the command can answer in one line (terl_rt.cli.main).
"""

__version__ = "0.1.0"
"""The package version (pyproject.toml reads it from here)."""

_HOMES = {
    "ConstantEvader": "terl_rt.sim.evader",
    "EvaderPolicy": "terl_rt.sim.evader",
    "PublishedAPFEvader": "terl_rt.sim.evader",
    "EpisodeMetrics": "terl_rt.sim.metrics",
    "Observation": "terl_rt.sim.observation",
    "WorldParams": "terl_rt.sim.params",
    "PAPER_SUITE": "terl_rt.sim.scenario",
    "Scenario": "terl_rt.sim.scenario",
    "ScenarioError": "terl_rt.sim.scenario",
    "Simulator": "terl_rt.sim.simulator",
    "StepInfo": "terl_rt.sim.simulator",
    "StepResult": "terl_rt.sim.world",
    "World": "terl_rt.sim.world",
    "Evaluation": "terl_rt.evaluation.evaluate",
    "evaluate": "terl_rt.evaluation.evaluate",
}
"""Each public name -> the module it comes from."""

__all__ = [*_HOMES, "__version__"]

TYPE_CHECKING = False
"""True for type checkers, which read the imports below (`X as X`: re-exported, as mypy
--strict wants; typing is not imported, see above)."""
if TYPE_CHECKING:
    from terl_rt.sim.evader import (
        ConstantEvader as ConstantEvader, EvaderPolicy as EvaderPolicy, PublishedAPFEvader as PublishedAPFEvader,
    )
    from terl_rt.sim.metrics import EpisodeMetrics as EpisodeMetrics
    from terl_rt.sim.observation import Observation as Observation
    from terl_rt.sim.params import WorldParams as WorldParams
    from terl_rt.sim.scenario import PAPER_SUITE as PAPER_SUITE, Scenario as Scenario, ScenarioError as ScenarioError
    from terl_rt.sim.simulator import Simulator as Simulator, StepInfo as StepInfo
    from terl_rt.sim.world import StepResult as StepResult, World as World
    from terl_rt.evaluation.evaluate import Evaluation as Evaluation, evaluate as evaluate


def __getattr__(name: str) -> object:
    """A public name, imported from its module on first use."""
    if name not in _HOMES:
        raise AttributeError(f"module 'terl_rt' has no attribute {name!r}")
    from importlib import import_module

    value = getattr(import_module(_HOMES[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})
