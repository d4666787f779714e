"""The maths of learning, as small pure helpers: schedules, TD targets, (quantile) Huber losses.

Letters: R batch rows (transitions), N online fractions, N' target fractions, A = 9 actions.
"""

from __future__ import annotations

import torch


def linear_schedule(start: float, end: float, duration: float, step: float) -> float:
    """Value falling (or rising) linearly from `start` at step 0 to `end` at `duration`, then `end`."""
    if duration <= 0:
        return end
    progress = min(max(step / duration, 0.0), 1.0)
    return start + progress * (end - start)


def huber(errors: torch.Tensor, kappa: float = 1.0) -> torch.Tensor:
    """Element-wise Huber loss: 0.5 u^2 for |u| <= kappa, else kappa (|u| - 0.5 kappa)."""
    magnitude = errors.abs()
    return torch.where(magnitude <= kappa, 0.5 * errors**2, kappa * (magnitude - 0.5 * kappa))


def td_target(
    rewards: torch.Tensor,
    dones: torch.Tensor,
    next_q: torch.Tensor,
    discounts: torch.Tensor,
    best: torch.Tensor | None = None,
) -> torch.Tensor:
    """DQN target r + discount * (1 - done) * Q_target(s', a*), a* = argmax_a Q_target(s', a),
    or `best` (double DQN: the online network's argmax).

    rewards [R], dones [R] (1.0 = no bootstrap), next_q [R, A], discounts [R] (gamma^k),
    best [R] int64 or None -> [R].
    """
    if best is None:
        best = next_q.argmax(dim=1)
    chosen = next_q.gather(1, best[:, None]).squeeze(1)
    return rewards + discounts * (1.0 - dones) * chosen


def quantile_td_target(
    rewards: torch.Tensor,
    dones: torch.Tensor,
    next_quantiles: torch.Tensor,
    discounts: torch.Tensor,
    best: torch.Tensor | None = None,
    per_fraction: bool = False,
) -> torch.Tensor:
    """IQN target quantiles r + discount * (1 - done) * Z_target(s', a*), a* = argmax_a mean_tau' Z_target,
    or `best` (double DQN: the online network's argmax); with `per_fraction`, max_a Z_target(s', a)
    at each fraction tau' on its own (the published trainer's target).

    rewards [R], dones [R], next_quantiles [R, N', A] (target network at the fractions tau'),
    discounts [R] (gamma^k), best [R] int64 or None -> [R, N'].
    """
    if per_fraction:
        if best is not None:
            raise ValueError("quantile_td_target: per_fraction takes an action at each fraction, best one for all")
        chosen = next_quantiles.amax(dim=2)
    else:
        if best is None:
            best = next_quantiles.mean(dim=1).argmax(dim=1)
        index = best[:, None, None].expand(-1, next_quantiles.shape[1], 1)
        chosen = next_quantiles.gather(2, index).squeeze(2)
    return rewards[:, None] + discounts[:, None] * (1.0 - dones[:, None]) * chosen


def quantile_huber_rows(
    quantiles: torch.Tensor, taus: torch.Tensor, targets: torch.Tensor, kappa: float = 1.0
) -> torch.Tensor:
    """Quantile Huber loss of IQN (Dabney et al. 2018, eq. 3) of each row: [R].

    quantiles [R, N] of the taken actions at fractions taus [R, N]; targets [R, N'].
    With u_ij = target_j - quantile_i: rho_ij = |tau_i - 1{u_ij < 0}| * Huber_kappa(u_ij) / kappa,
    summed over i and averaged over j.
    """
    errors = targets[:, None, :] - quantiles[:, :, None]  # [R, N, N']
    weight = (taus[:, :, None] - (errors.detach() < 0).to(errors.dtype)).abs()
    rho = weight * huber(errors, kappa) / kappa
    return rho.mean(dim=2).sum(dim=1)


def quantile_huber_loss(
    quantiles: torch.Tensor, taus: torch.Tensor, targets: torch.Tensor, kappa: float = 1.0
) -> torch.Tensor:
    """`quantile_huber_rows` averaged over the rows, a scalar."""
    return quantile_huber_rows(quantiles, taus, targets, kappa).mean()
