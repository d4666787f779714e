"""`python -m terl_rt ...`: the `terl-rt` command, for environments whose scripts folder is not on PATH."""

from terl_rt.cli import main

main()
