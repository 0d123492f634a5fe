"""Helpers shared by the compared networks' tests."""

from __future__ import annotations

import torch


def count_params(module: torch.nn.Module) -> int:
    """Every parameter of ``module``."""
    return sum(p.numel() for p in module.parameters())


def randomise_norms(model: torch.nn.Module, seed: int = 0) -> None:
    """Non-trivial BatchNorm statistics and affine terms, so eval differs from identity
    (running mean, running variance, weight, bias drawn in that order from ``seed``)."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                n = m.num_features
                m.running_mean.copy_(torch.rand(n, generator=gen) - 0.5)
                m.running_var.copy_(torch.rand(n, generator=gen) + 0.5)
                m.weight.copy_(torch.rand(n, generator=gen) + 0.5)
                m.bias.copy_(torch.rand(n, generator=gen) - 0.5)
