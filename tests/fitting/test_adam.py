"""The fitting loops' Adam against torch.optim.Adam."""

from __future__ import annotations

import torch

from head360cli.fitting.adam import Adam


def _loss(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a.sin() ** 2).sum() + (b - 1.0).abs().sum() * a.sum() ** 2


def test_adam_follows_torch_adam_step_for_step():
    torch.manual_seed(0)
    ours = [torch.randn(5, 3, requires_grad=True), torch.randn(4, requires_grad=True)]
    theirs = [p.detach().clone().requires_grad_(True) for p in ours]
    unused = torch.zeros(2, requires_grad=True)  # never has a gradient: left alone
    opt = Adam([{"params": [ours[0], unused], "lr": 0.05}, {"params": [ours[1]]}], lr=0.3)
    ref = torch.optim.Adam([{"params": [theirs[0]], "lr": 0.05},
                            {"params": [theirs[1]]}], lr=0.3)
    start = float(_loss(*ours).detach())
    for _ in range(25):
        for params, o in ((ours, opt), (theirs, ref)):
            loss = _loss(*params)
            o.zero_grad()
            loss.backward()
            o.step()
    for a, b in zip(ours, theirs, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-6)
    assert unused.abs().max() == 0
    assert float(_loss(*ours).detach()) < 0.5 * start  # it did optimise


def test_adam_takes_a_plain_list_and_zero_grad_clears():
    x = torch.ones(3, requires_grad=True)
    opt = Adam([x], lr=0.1)
    (x * x).sum().backward()
    opt.step()
    torch.testing.assert_close(x.detach(), torch.full((3,), 0.9))  # first step: lr * sign
    opt.zero_grad()
    assert x.grad is None
