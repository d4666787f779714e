"""The paper's report wing: a policy's results set against the TERL paper's published
numbers (the report), several policies against its comparison (claims, Tables III and IV,
Fig. 3), the comparison over training seeds (rliable's statistics, its figure and files, the
marl-eval export), and a comparison's finished evaluations kept until its files are written.
It reads what terl_rt.evaluation runs; the evaluation core never imports it."""
