"""Adam over rows of flat weights, each row a seed's, by the kernel torch.optim.Adam(fused=True) runs.

torch.optim.Adam(fused=True) steps its parameters with one ATen operation, `torch._fused_adam_`,
after adding one to their step counts. `RowAdam` makes the same two calls on the same tensors,
so the bytes are those of torch.optim.Adam (tests/training/test_adam.py checks it), without
torch.optim's Optimizer: each of its methods imports torch._dynamo on first use, 2-3 s of CPU
at the start of every training process, for a compiler training never uses.

A seed's state is torch's: {"step": [] float32 on the row's device, "exp_avg": [P], "exp_avg_sq": [P]}.
`one_seed_state_dict` gives it in the layout of a plain torch.optim.Adam's state_dict over a
network's parameters, the layout every checkpoint holds.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch

BETAS = (0.9, 0.999)
EPS = 1e-8
"""torch.optim.Adam's defaults, which training uses: no weight decay, no AMSGrad."""

AdamState = dict[str, torch.Tensor]


class RowAdam:
    """Adam over `rows` [S] of weights [P] each, with their gradients `gradients` [S] (views
    that the backward pass fills); each row keeps its own state and step count."""

    def __init__(self, rows: Sequence[torch.Tensor], gradients: Sequence[torch.Tensor], learning_rate: float,
                 states: Sequence[AdamState | None] | None = None) -> None:
        if len(rows) != len(gradients):
            raise ValueError(f"RowAdam: {len(rows)} rows of weights and {len(gradients)} of gradients")
        self.rows = list(rows)
        self.gradients = list(gradients)
        self.learning_rate = learning_rate
        self.states: list[AdamState | None] = list(states) if states is not None else [None] * len(rows)
        """[S] each row's state, None before its first step."""

    @torch.no_grad()
    def step(self) -> None:
        """One Adam step of every row on its gradient."""
        for k, row in enumerate(self.rows):
            if self.states[k] is None:
                self.states[k] = {
                    "step": torch.zeros((), dtype=torch.float32, device=row.device),
                    "exp_avg": torch.zeros_like(row),
                    "exp_avg_sq": torch.zeros_like(row),
                }
        states = [state for state in self.states if state is not None]
        steps = [state["step"] for state in states]
        torch._foreach_add_(steps, 1)
        torch._fused_adam_(
            self.rows, self.gradients, [state["exp_avg"] for state in states],
            [state["exp_avg_sq"] for state in states], [], steps,
            lr=self.learning_rate, beta1=BETAS[0], beta2=BETAS[1], weight_decay=0.0, eps=EPS, amsgrad=False,
            maximize=False, grad_scale=None, found_inf=None,
        )


def one_seed_state_dict(
    count: int, learning_rate: float, step: torch.Tensor | None = None,
    moments: Sequence[tuple[torch.Tensor, torch.Tensor]] = (),
) -> dict[str, Any]:
    """A plain torch.optim.Adam's state_dict over a network's `count` parameters (CPU copies):
    `moments` holds each parameter's (exp_avg, exp_avg_sq) in `parameters()` order after `step`
    steps; no step yet (None), no state."""
    state = {} if step is None else {
        index: {
            "step": step.detach().cpu().clone(),
            "exp_avg": exp_avg.detach().cpu().clone(),
            "exp_avg_sq": exp_avg_sq.detach().cpu().clone(),
        }
        for index, (exp_avg, exp_avg_sq) in enumerate(moments)
    }
    group = {
        "lr": learning_rate, "betas": BETAS, "eps": EPS, "weight_decay": 0, "amsgrad": False, "maximize": False,
        "foreach": None, "capturable": False, "differentiable": False, "fused": None, "decoupled_weight_decay": False,
        "params": list(range(count)),
    }
    return {"state": state, "param_groups": [group]}
