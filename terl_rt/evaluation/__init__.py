"""Measuring policies and the simulator: evaluation episodes, speed benchmarks, the
paper's published numbers, the report that sets a policy against them and the
comparison that sets several against the paper's."""
