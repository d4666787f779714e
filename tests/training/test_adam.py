"""RowAdam steps rows of flat weights to the bytes torch.optim.Adam(fused=True) gives, and
writes a seed's state in the layout of a plain torch.optim.Adam's state_dict."""

from __future__ import annotations

import torch

from training.adam import RowAdam, one_seed_state_dict


def test_row_adam_gives_the_bytes_of_torch_adam_fused_row_by_row_through_a_change_of_step_size():
    generator = torch.Generator().manual_seed(0)
    weights = torch.randn(3, 50, generator=generator)
    gradients = [torch.randn(3, 50, generator=generator) * scale for scale in (1.0, 1e-3, 30.0, 0.5)]
    rows = [torch.nn.Parameter(weights[k].clone()) for k in range(3)]
    reference = torch.optim.Adam(rows, lr=1e-3, fused=True)
    flat, flat_gradients = weights.clone(), torch.zeros(3, 50)
    adam = RowAdam(list(flat), list(flat_gradients), learning_rate=1e-3)
    for step, gradient in enumerate(gradients):
        if step == 2:  # the schedule's falling step size
            reference.param_groups[0]["lr"] = adam.learning_rate = 2e-4
        for k, row in enumerate(rows):
            row.grad = gradient[k].clone()
        flat_gradients.copy_(gradient)
        reference.step()
        adam.step()
        assert torch.equal(torch.stack([row.detach() for row in rows]), flat), step
    for k, row in enumerate(rows):
        assert all(torch.equal(reference.state[row][key], adam.states[k][key]) for key in ("step", "exp_avg", "exp_avg_sq"))


def test_a_seeds_state_dict_is_a_plain_adams_that_it_loads_into():
    model = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.Linear(4, 2))
    plain = torch.optim.Adam(model.parameters(), lr=5e-4)
    assert one_seed_state_dict(4, 5e-4) == plain.state_dict()  # before the first step: no state
    moments = [(torch.full_like(p, 0.1), torch.full_like(p, 0.2)) for p in model.parameters()]
    written = one_seed_state_dict(4, 5e-4, torch.tensor(7.0), moments)
    plain.load_state_dict(written)
    for p, (exp_avg, exp_avg_sq) in zip(model.parameters(), moments):
        assert float(plain.state[p]["step"]) == 7.0
        assert torch.equal(plain.state[p]["exp_avg"], exp_avg) and torch.equal(plain.state[p]["exp_avg_sq"], exp_avg_sq)
    assert plain.state_dict()["param_groups"] == written["param_groups"]
