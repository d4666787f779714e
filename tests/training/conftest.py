"""Training tests run torch on one thread: two threads that share the cores with another
process (a parallel test run, a training run) stall on each other, up to 7x slower."""

import pytest
import torch


@pytest.fixture(autouse=True)
def one_torch_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)
