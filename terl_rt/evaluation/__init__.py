"""Measuring policies and the simulator: evaluation episodes and where they run (this
process, worker processes or Ray tasks), sweeps over policies and scenarios, speed
benchmarks, the paper's published numbers, the report that sets a policy against them
and the comparison that sets several against the paper's."""
