"""Adam for the fitting loops, without ``torch.optim``.

``torch.optim.Optimizer`` imports torch's compiler (``torch._dynamo``) the first time an
optimizer is made, to mark its methods as not compilable: 1.0-1.5 s on this project's
2-core machine, a tenth of a fast fit, for a compiler the fit never uses. The few lines
below are the same update as ``torch.optim.Adam`` with its defaults (no weight decay, no
amsgrad), so fits match it to float rounding (checked in the tests).
"""

from __future__ import annotations

from collections.abc import Iterable

import torch

__all__ = ["Adam"]


class Adam:
    """Adam over parameter groups, the update of ``torch.optim.Adam``.

    Args:
        groups: Tensors (one group at ``lr``) or dicts ``{"params": [...], "lr": x}``.
        lr: Learning rate of groups that do not give one.
        betas: Decay rates of the first and second moment estimates.
        eps: Added to the denominator.
    """

    def __init__(self, groups: Iterable, lr: float = 1e-3,
                 betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8) -> None:
        groups = list(groups)
        if groups and isinstance(groups[0], torch.Tensor):
            groups = [{"params": groups}]
        self.groups = [{"params": list(g["params"]), "lr": float(g.get("lr", lr))}
                       for g in groups]
        self.betas = betas
        self.eps = eps
        self.state: dict[int, list] = {}

    def zero_grad(self) -> None:
        """Forget the gradients (set them to ``None``, as torch does by default)."""
        for group in self.groups:
            for p in group["params"]:
                p.grad = None

    @torch.no_grad()
    def step(self) -> None:
        """One update of every parameter that has a gradient (each counts its own
        steps for the bias corrections, as torch's does)."""
        b1, b2 = self.betas
        for group in self.groups:
            for p in group["params"]:
                if p.grad is None:
                    continue
                state = self.state.setdefault(
                    id(p), [0, torch.zeros_like(p), torch.zeros_like(p)])
                state[0] += 1
                count, mean, square = state
                mean.lerp_(p.grad, 1.0 - b1)
                square.mul_(b2).addcmul_(p.grad, p.grad, value=1.0 - b2)
                denom = (square.sqrt() / (1.0 - b2 ** count) ** 0.5).add_(self.eps)
                p.addcdiv_(mean, denom, value=-group["lr"] / (1.0 - b1 ** count))
