"""PettingZoo's own checks of terl_rt.envs: parallel_api_test, parallel_seed_test, and
api_test through parallel_to_aec."""

import warnings

from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test
from pettingzoo.utils.conversions import parallel_to_aec

from terl_rt import Scenario
from terl_rt.envs import parallel_env

warnings.filterwarnings("ignore", "Observation", UserWarning)  # advice for Box observations; ours are a Dict
short = Scenario.preset("small-11").replace(max_steps=30)
parallel_api_test(parallel_env(short, seed=0), num_cycles=60)
parallel_seed_test(lambda: parallel_env(short), num_cycles=30)
api_test(parallel_to_aec(parallel_env(short, seed=0)), num_cycles=20)
print("pettingzoo: parallel_api_test, parallel_seed_test, api_test passed")
