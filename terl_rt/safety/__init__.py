"""Safety at run time, for any policy: a decentralised shield (`shield`: each pursuer
predicts, from its own observation, what each of its actions leads to and drops those
that come too close to anything), risk-aware acting from an IQN head's quantiles (`risk`:
act on the CVaR of the returns instead of their mean), and the rule that joins them to a
policy's outputs (`acting`). docs/safety.md explains both and their defaults.

This file imports nothing, so that `terl_rt.safety.shield` loads without onnxruntime.
"""
