"""Running a policy's episodes: evaluation episodes and where they run (this process, worker
processes or Ray tasks), their statistics, sweeps over policies and scenarios, speed
benchmarks and optimised variants of a policy. What sets results against the paper is
terl_rt.paper."""
