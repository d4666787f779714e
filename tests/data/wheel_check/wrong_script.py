"""A user's script with a type error that mypy finds only through terl-rt's annotations."""

from terl_rt import Scenario

pursuers: str = Scenario.preset("small-15").pursuers
