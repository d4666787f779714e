"""Measuring policies and the simulator: evaluation episodes, speed benchmarks, the
paper's published numbers and the report that sets a policy against them."""
