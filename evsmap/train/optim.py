"""The optimiser's schedule and the training loss of ``evsmap train``: the learning rate of
epoch ``e`` is ``lr * recipe.lr_factor(e)`` (:func:`evsmap.train.recipe.poly_factor`), set when
the epoch starts; every output head gets the hybrid loss of eq. 1
(:class:`~evsmap.losses.HybridLoss`, void ignored) against the labels resized to its size
(:class:`~evsmap.losses.MultiScaleLoss`), the main head with weight 1 and each side head with the
recipe's ``side_weight``."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from torch import nn

from evsmap.losses import HybridLoss, MultiScaleLoss
from evsmap.train.recipe import Recipe


class EpochSchedule:
    """The learning rate of each epoch, ``base_lr * factor(epoch)``, set when the epoch starts
    (the factor comes from the recipe, so a resumed run with more epochs follows the new
    schedule)."""

    def __init__(self, optimizer: torch.optim.Optimizer, factor: Callable[[int], float]) -> None:
        self.optimizer = optimizer
        self.factor = factor
        self.base_lrs = [float(g["lr"]) for g in optimizer.param_groups]
        self.epoch = 0

    def start(self, epoch: int) -> float:
        """Set the rates of 0-based ``epoch``; returns the first group's."""
        self.epoch = int(epoch)
        for group, base in zip(self.optimizer.param_groups, self.base_lrs, strict=True):
            group["lr"] = base * self.factor(epoch)
        return float(self.optimizer.param_groups[0]["lr"])

    def state_dict(self) -> dict[str, Any]:
        return {"base_lrs": list(self.base_lrs), "epoch": self.epoch}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.base_lrs = [float(v) for v in state["base_lrs"]]
        self.epoch = int(state["epoch"])


class TrainingLoss(nn.Module):
    """Eq. 1 on every output head: ``main + side_weight * sum(sides)`` (see the module notes)."""

    def __init__(self, recipe: Recipe) -> None:
        super().__init__()
        self.hybrid = HybridLoss(alpha=recipe.alpha, beta=recipe.beta,
                                 smooth_factor=recipe.label_smoothing)
        self.side_weight = recipe.side_weight
        self._by_heads: dict[int, MultiScaleLoss] = {}

    def forward(self, outputs: torch.Tensor | tuple[torch.Tensor, ...],
                labels: torch.Tensor) -> torch.Tensor:
        heads = 1 if isinstance(outputs, torch.Tensor) else len(outputs)
        loss = self._by_heads.get(heads)
        if loss is None:
            loss = MultiScaleLoss(loss=self.hybrid,
                                  weights=(1.0,) + (self.side_weight,) * (heads - 1))
            self._by_heads[heads] = loss
        return loss(outputs, labels)


__all__ = ["EpochSchedule", "TrainingLoss"]
