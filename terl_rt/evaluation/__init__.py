"""Measuring policies and the simulator: evaluation episodes and where they run (this
process, worker processes or Ray tasks), sweeps over policies and scenarios, speed
benchmarks, the paper's published numbers and the report that sets a policy against them."""
