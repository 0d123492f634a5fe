"""The training loop of ``evsmap train``: one process, or DDP under ``torchrun``.

:func:`train` sets the run up (:func:`evsmap.train.setup.set_up`: model, data, optimiser,
schedule, AMP, DDP, one function each), then an :class:`~evsmap.train.trainer.EpochTrainer`
(the SGD steps of an epoch) runs the epochs of :class:`~evsmap.train.engine.TrainerBase`'s short
loop, and hooks do the rest (:mod:`evsmap.train.hooks`: validation, best model, checkpoints and
resume, messages and progress bars, the final test pass, interruption).

* **Model**: the registered segmenter's network (``SEGMENTERS.create(name, **options)``); in
  training mode it returns its side outputs too, and every head gets the hybrid loss of eq. 1
  (:class:`~evsmap.losses.HybridLoss`, void ignored) against the labels resized to its size
  (:class:`~evsmap.losses.MultiScaleLoss`), the main head with weight 1 and each side head with
  the recipe's ``side_weight``.
* **Optimiser and schedule**: SGD; the learning rate of epoch ``e`` is ``lr * recipe.lr_factor(e)``
  (:func:`evsmap.train.recipe.poly_factor`), set at the start of the epoch
  (:mod:`evsmap.train.optim`).
* **Data**: :class:`~evsmap.train.data.TrainingFrames` through a ``DistributedSampler`` (shuffled
  with ``seed + epoch``, also with one process) and a ``DataLoader``; the recipe's batch is the
  global batch, split evenly over the processes.
* **Determinism**: every epoch starts by seeding torch, numpy and Python from (seed, epoch,
  rank), and samples draw their augmentation from (seed, epoch, frame); the run keeps torch's
  intra-op thread count fixed (recorded in ``run.json``: convolutions split their sums by it);
  a resume takes the run's settings from its ``run.json`` (:mod:`evsmap.train.settings`) and
  its optimiser, schedule, AMP scaler, random states and torch's algorithm flags from its
  checkpoint. So a run stopped after any epoch and resumed repeats the straight run bit for
  bit on the CPU, and on a GPU with ``--deterministic``.
* **Validation** (every ``eval_every`` epochs and after the last): the network in eval mode
  predicts every frame of the validation split exactly as ``evsmap eval`` does
  (``NetworkSegmenter.predict``, at the segmenter's input size; on a GPU the same computation
  with the tensors moved there), and one confusion matrix gives the mIoU
  (:mod:`evsmap.metrics.segmentation`). Processes share the frames and sum their matrices.
* **DDP**: launched by ``torchrun`` (``WORLD_SIZE`` > 1 in the environment): gloo on the CPU,
  nccl on CUDA (one GPU per process, ``LOCAL_RANK``), SyncBatchNorm on CUDA when the recipe
  asks. Only rank 0 writes files and prints.
* **AMP**: ``amp = true`` on CUDA runs the forward pass under ``torch.autocast`` (float16) with
  a ``GradScaler``; the losses compute in float32.
* **Files** (rank 0, after every epoch, each atomically): ``best.pt``, ``last.pt``, ``log.csv``,
  ``run.json``, then ``checkpoint.pt`` (see :mod:`evsmap.train.checkpoint`).
* **Final test pass** (rank 0, after the last epoch, when the run validated on a split other
  than ``test`` and the dataset has a labelled ``test`` split - synthrooms; not Cityscapes, whose
  test labels are all void): ``best.pt``'s weights predict the test split as in validation, and
  ``test_miou``, ``test_split`` and ``test_frames`` go into its card and ``run.json``
  (:func:`evsmap.train.evaluate.final_test`).
* **Interruption**: Ctrl-C or SIGTERM drops the epoch under way; ``checkpoint.pt`` holds the last
  finished one, and ``--resume`` continues from it as if never stopped.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import torch
import torch.distributed as dist

from evsmap.train.checkpoint import (
    BEST,
    CHECKPOINT,
    LAST,
    LOG,
    RUN,
    backend_flags,
    set_backend_flags,
)
from evsmap.train.hooks import default_hooks
from evsmap.train.options import RunOptions
from evsmap.train.processes import start_processes
from evsmap.train.settings import with_recorded_settings
from evsmap.train.setup import set_up
from evsmap.train.trainer import EpochTrainer


def train(opts: RunOptions) -> dict[str, Any]:
    """Run (or resume) a training run; returns a summary (rank 0's; other ranks' are equal
    but for the files they did not write). torch's process-wide settings the run changes (its
    thread count, the algorithm flags) are put back when it ends."""
    opts = with_recorded_settings(opts)
    procs = start_processes(opts.device)
    flags, threads = backend_flags(), torch.get_num_threads()
    pinned = opts.threads or threads
    opts = dataclasses.replace(opts, threads=pinned)
    torch.set_num_threads(pinned)
    if opts.deterministic:  # cuBLAS reads it when its handle is made, before the first matmul
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
    try:
        run = set_up(opts, procs)
        trainer = EpochTrainer(run)
        trainer.register_hooks(default_hooks(run))
        end = run.recipe.epochs
        if opts.stop_after is not None:
            end = min(end, run.start + opts.stop_after)
        trainer.train(run.start, end)
        summary = _summary(trainer)
        if procs.world > 1:
            dist.barrier()
        return summary
    finally:
        set_backend_flags(flags)
        torch.set_num_threads(threads)
        if procs.started and dist.is_initialized():
            dist.destroy_process_group()


def _summary(trainer: EpochTrainer) -> dict[str, Any]:
    run, best = trainer.run, trainer.best
    return {
        "out": str(run.out), "model": run.opts.model, "dataset": run.opts.dataset,
        "options": run.options, "threads": run.opts.threads, "epochs": trainer.epoch,
        "epochs_planned": run.recipe.epochs, "finished": trainer.epoch >= run.recipe.epochs,
        "best_epoch": best["epoch"] if best else None,
        "best_val_miou": best["val_miou"] if best else None, "last_val_miou": trainer.last_val,
        "test_miou": (trainer.test or {}).get("test_miou"), "world_size": run.procs.world,
        "files": {name: str(run.out / name) for name in (CHECKPOINT, LAST, BEST, LOG, RUN)
                  if (run.out / name).exists()},
    }


__all__ = ["RunOptions", "train"]
