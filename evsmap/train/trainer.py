"""What an epoch of ``evsmap train`` is: :class:`EpochTrainer` runs SGD steps over this
process's batches (the forward pass under ``torch.autocast`` with AMP) and sums the epoch's
loss and images over the processes; everything else is a hook (:mod:`evsmap.train.hooks`).

Every epoch starts by setting its learning rate, the sampler's epoch and the training mode, and
seeding torch, numpy and Python from (seed, epoch, rank) (see :mod:`evsmap.train.loop`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any

import torch

from evsmap.errors import EvsmapError
from evsmap.train.checkpoint import cpu_state, derived_seed, seed_everything
from evsmap.train.engine import TrainerBase
from evsmap.train.setup import TrainingRun


@dataclass
class EpochResult:
    """The figures of one epoch, filled in by the trainer and the hooks.

    Attributes:
        epoch: epochs done after this one (1-based).
        lr: the learning rate of the first parameter group.
        loss: the mean loss of the epoch's steps over all processes.
        images: images of all processes.
        train_seconds: time of the steps, data loading included.
        val, val_seconds: the validation mIoU (None: not validated, or no labelled pixel) and
            its time.
        ranks: each process's images, frames and parameter hash (DDP runs).
        improved: the epoch is the best so far (:class:`evsmap.train.hooks.BestModel`).
    """

    epoch: int
    lr: float
    loss: float = math.nan
    images: int = 0
    train_seconds: float = 0.0
    val: float | None = None
    val_seconds: float = 0.0
    ranks: list[Any] | None = None
    improved: bool = False

    @property
    def images_per_s(self) -> float | None:
        return round(self.images / self.train_seconds, 3) if self.train_seconds else None

    def log_row(self) -> dict[str, Any]:
        """The epoch's row of ``log.csv`` (and of the checkpoint's history)."""
        return {"epoch": self.epoch, "lr": self.lr, "loss": self.loss, "val_miou": self.val,
                "train_seconds": round(self.train_seconds, 3),
                "val_seconds": round(self.val_seconds, 3),
                "seconds": round(self.train_seconds + self.val_seconds, 3),
                "images": self.images, "images_per_s": self.images_per_s}


class EpochTrainer(TrainerBase):
    """SGD epochs over a :class:`~evsmap.train.setup.TrainingRun`.

    Attributes:
        run: what is trained, on what, how.
        history: the log rows of the run's epochs (rank 0 adds to it).
        best: ``{"epoch", "val_miou"}`` of the best epoch so far, None before any validation.
        last_val: the latest validation mIoU.
        result: the figures of the current (or last) epoch.
        step_loss: the loss of the latest step.
        test: the final test pass's fields, when there was one.
    """

    def __init__(self, run: TrainingRun) -> None:
        super().__init__()
        self.run = run
        self.history: list[dict[str, Any]] = []
        self.best: dict[str, Any] | None = None
        self.last_val: float | None = None
        self.result = EpochResult(epoch=0, lr=math.nan)
        self.step_loss: torch.Tensor | None = None
        self.test: dict[str, Any] | None = None
        self._batches: Iterator[Any] = iter(())
        self._t0 = 0.0
        self._loss_sum = torch.zeros((), dtype=torch.float64)
        self._images = 0
        self._seen: list[int] = []
        self._state: dict[str, torch.Tensor] | None = None

    def open_epoch(self) -> None:
        run, procs = self.run, self.run.procs
        lr = run.optim.schedule.start(self.epoch)
        run.data.sampler.set_epoch(self.epoch)
        run.net.module.train()
        self._batches = iter(run.data.loader)
        seed_everything(derived_seed(run.recipe.seed, self.epoch, procs.rank))
        self._t0 = time.perf_counter()
        self._loss_sum = torch.zeros((), dtype=torch.float64, device=procs.device)
        self._images, self._seen, self._state = 0, [], None
        self.result = EpochResult(epoch=self.epoch + 1, lr=lr)

    def batches(self) -> Iterable[Any]:
        return _batches(self._batches)

    def run_step(self, batch: dict[str, torch.Tensor]) -> None:
        device, optim = self.run.procs.device, self.run.optim
        labels = batch["labels"].to(device, non_blocking=True)
        names = ("rgb", "depth") if "depth" in batch else ("rgb",)
        memory = torch.channels_last if self.run.opts.channels_last else torch.contiguous_format
        inputs = [batch[n].to(device, non_blocking=True).contiguous(memory_format=memory)
                  for n in names]
        with torch.autocast(device.type, dtype=torch.float16, enabled=optim.amp):
            outputs = self.run.model(*inputs)
        loss = optim.criterion(outputs, labels)
        optim.optimizer.zero_grad(set_to_none=True)
        optim.scaler.scale(loss).backward()
        optim.scaler.step(optim.optimizer)
        optim.scaler.update()
        self._loss_sum += loss.detach().double()
        self._images += int(labels.shape[0])
        self._seen.extend(int(i) for i in batch["index"])
        self.step_loss = loss

    def close_epoch(self) -> None:
        """The epoch's mean loss and images over the processes (an error when the loss is not
        finite), and in a DDP run each process's share."""
        procs, steps = self.run.procs, self.run.data.steps
        if procs.device.type == "cuda":
            torch.cuda.synchronize(procs.device)
        train_seconds = time.perf_counter() - self._t0
        totals = torch.tensor([float(self._loss_sum), float(steps), float(self._images)],
                              dtype=torch.float64,
                              device=procs.device if procs.backend == "nccl" else "cpu")
        totals = procs.sum_(totals).cpu()
        mean_loss = float(totals[0] / totals[1])
        if not math.isfinite(mean_loss):
            raise EvsmapError(f"the loss is {mean_loss} after epoch {self.epoch + 1}: lower the "
                              f"learning rate (--lr) or check the labels")
        result = self.result
        result.loss, result.images, result.train_seconds = mean_loss, int(totals[2]), \
            train_seconds
        if procs.world > 1:
            result.ranks = procs.gather({"rank": procs.rank, "images": self._images,
                                         "indices": self._seen,
                                         "params_sha256": _params_sha256(self.run.net.module)})

    def weights(self) -> dict[str, torch.Tensor]:
        """The network's state on the CPU after the current epoch (copied once an epoch)."""
        if self._state is None:
            self._state = cpu_state(self.run.net.module.state_dict())
        return self._state


def _batches(batches: Iterator[Any]) -> Iterator[Any]:
    """The loader's batches; an :class:`EvsmapError` raised in a data-loading process (which
    the loader re-raises with the worker's traceback as its message) back to its one line."""
    try:
        yield from batches
    except EvsmapError as exc:
        text = str(exc)
        if "Original Traceback" not in text:
            raise
        last = [line for line in text.splitlines() if line.strip()][-1]
        name = f"{type(exc).__module__}.{type(exc).__qualname__}: "
        raise type(exc)(last.split(name, 1)[1] if name in last else last) from None


def _params_sha256(module: torch.nn.Module) -> str:
    from evsmap.segmenters.cards import tensor_sha256

    return tensor_sha256(dict(module.named_parameters()))


__all__ = ["EpochResult", "EpochTrainer"]
