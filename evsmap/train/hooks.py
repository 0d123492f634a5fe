"""The hooks of ``evsmap train``'s trainer (:class:`~evsmap.train.trainer.EpochTrainer`), in the
order :func:`default_hooks` registers them - the order they run in at each point:

* :class:`ProgressBar`: a bar over the steps of each epoch (rank 0, on a terminal).
* :class:`Evaluator`: validation every ``eval_every`` epochs and after the last (all ranks).
* :class:`BestModel`: ``best.pt`` when the validation mIoU beats the best so far (rank 0).
* :class:`Checkpointer`: restores a resumed run when training starts (all ranks); after every
  epoch ``last.pt``, ``log.csv``, ``run.json`` and ``checkpoint.pt`` (rank 0).
* :class:`EpochLog`: the lines rank 0 prints (what is trained, one line an epoch).
* :class:`FinalTest`: the final test pass of ``best.pt`` after the last epoch (rank 0).
* :class:`Interrupt`: Ctrl-C or SIGTERM stop the run where it is (all ranks).

So after every epoch the files are written in the order ``best.pt``, ``last.pt``, ``log.csv``,
``run.json``, ``checkpoint.pt``, each atomically, and then the epoch's line is printed.
"""

from __future__ import annotations

import json
import math
import sys
import time
from typing import Any

import torch.distributed as dist
from tqdm import tqdm

from evsmap.errors import EvsmapError
from evsmap.fileio import atomic_write_text
from evsmap.interrupt import reraise_interruption
from evsmap.train.checkpoint import (
    BEST,
    CHECKPOINT,
    FORMAT,
    LAST,
    LOG,
    RUN,
    VERSION,
    atomic_save,
    backend_flags,
    log_csv,
    rng_state,
    save_weights,
    set_backend_flags,
    set_rng_state,
)
from evsmap.train.engine import HookBase
from evsmap.train.evaluate import card_has_test, final_test, percent, validate
from evsmap.train.setup import Optimisation, TrainingRun
from evsmap.train.trainer import EpochTrainer


class ProgressBar(HookBase[EpochTrainer]):
    """A bar over the epoch's steps with the loss and learning rate (shown on rank 0 when
    stderr is a terminal), closed at the end of the epoch or when training stops."""

    def __init__(self) -> None:
        self._bar: tqdm | None = None

    def before_epoch(self, trainer: EpochTrainer) -> None:
        run = trainer.run
        self._bar = tqdm(total=run.data.steps, desc=f"epoch {trainer.epoch + 1}/"
                         f"{run.recipe.epochs}", unit="step", leave=False, file=sys.stderr,
                         disable=not run.tty)

    def after_step(self, trainer: EpochTrainer) -> None:
        if self._bar is not None and trainer.run.tty and trainer.step_loss is not None:
            self._bar.update(1)
            self._bar.set_postfix(loss=f"{trainer.step_loss.item():.4f}",
                                  lr=f"{trainer.result.lr:.2e}")

    def after_epoch(self, trainer: EpochTrainer) -> None:
        self._close()

    def on_exception(self, trainer: EpochTrainer, exc: BaseException) -> None:
        self._close()

    def _close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None


class Evaluator(HookBase[EpochTrainer]):
    """Validation every ``eval_every`` epochs and after the last: the network in eval mode
    predicts the validation split as ``evsmap eval`` does, the processes share the frames (with
    rank 0's BatchNorm statistics, the ones saved) and sum their confusion matrices."""

    def after_epoch(self, trainer: EpochTrainer) -> None:
        from evsmap.metrics import ConfusionMatrix

        run, result = trainer.run, trainer.result
        every = run.recipe.eval_every
        if not every or (result.epoch % every and result.epoch != run.recipe.epochs):
            return
        t1 = time.perf_counter()
        if run.procs.world > 1:  # rank 0's BatchNorm statistics, the ones saved
            for buffer in run.net.module.buffers():
                dist.broadcast(buffer, src=0)
        run.net.module.eval()
        counts = validate(run.net.segmenter, run.data.splits.val, run.procs, bar=run.tty)
        miou = ConfusionMatrix.from_matrix(counts).result().miou
        result.val = None if math.isnan(miou) else float(miou)
        result.val_seconds = time.perf_counter() - t1
        trainer.last_val = result.val


class BestModel(HookBase[EpochTrainer]):
    """``best.pt``: the weights of the epoch with the highest validation mIoU (the first of
    equals), with their card (rank 0)."""

    def after_epoch(self, trainer: EpochTrainer) -> None:
        result, best = trainer.result, trainer.best
        result.improved = result.val is not None and (best is None or
                                                      result.val > best["val_miou"])
        if not result.improved:
            return
        trainer.best = {"epoch": result.epoch, "val_miou": result.val}
        state = trainer.weights()
        save_weights(trainer.run.out / BEST, state,
                     trainer.run.card(state, result.epoch, result.val, result.epoch))


class Checkpointer(HookBase[EpochTrainer]):
    """The resume point. When training starts: a resumed run's weights, optimiser, schedule,
    AMP scaler, random states, torch's algorithm flags, history and best epoch come back from
    its checkpoint (all ranks), and rank 0 creates the run's folder. After every epoch (rank
    0): ``last.pt``, ``log.csv``, ``run.json``, ``checkpoint.pt`` (see
    :mod:`evsmap.train.checkpoint`)."""

    def before_train(self, trainer: EpochTrainer) -> None:
        run = trainer.run
        if run.saved is not None:
            _restore(trainer, run.saved)
        if run.procs.main:
            try:
                run.out.mkdir(parents=True, exist_ok=True)
            except OSError as exc:  # a file on the way, no permission: one line, no traceback
                raise EvsmapError(f"--out {run.out}: cannot create the run's folder "
                                  f"({exc.strerror or type(exc).__name__})") from None

    def after_epoch(self, trainer: EpochTrainer) -> None:
        run, result = trainer.run, trainer.result
        if not run.procs.main:
            return
        trainer.history.append(result.log_row())
        state = trainer.weights()
        last_card = run.card(state, result.epoch, result.val,
                             result.epoch if result.val is not None else None)
        save_weights(run.out / LAST, state, last_card)
        atomic_write_text(run.out / LOG, log_csv(trainer.history), durable=True)
        run.run_json.update(epochs_done=result.epoch, best=trainer.best, ranks=result.ranks,
                            evsmap_version=last_card["evsmap_version"],
                            git_commit=last_card["git_commit"])
        write_run_json(run)
        atomic_save({
            "format": FORMAT, "version": VERSION, "state_dict": state, "card": last_card,
            **carried_state(run.optim), "epoch": result.epoch, "recipe": run.recipe.as_dict(),
            "run": run.run_json, "history": trainer.history, "best": trainer.best,
        }, run.out / CHECKPOINT)


def carried_state(optim: Optimisation) -> dict[str, Any]:
    """What a straight run carries into its next epoch besides the weights, for the
    checkpoint: the optimiser (momentum buffers), the schedule, AMP's grad scaler (its scale and
    growth tracker; None without AMP), torch's (CPU and CUDA), numpy's and Python's random
    states, and torch's algorithm flags (cuDNN's autotuner and determinism, TF32,
    deterministic algorithms)."""
    return {"optimizer": optim.optimizer.state_dict(), "scheduler": optim.schedule.state_dict(),
            "scaler": optim.scaler.state_dict() if optim.amp else None, "rng": rng_state(),
            "backends": backend_flags()}


def restore_carried_state(optim: Optimisation, saved: dict[str, Any]) -> None:
    """Put back what :func:`carried_state` saved in checkpoint ``saved`` (a checkpoint from
    before the algorithm flags were saved keeps the flags this run set)."""
    optim.optimizer.load_state_dict(saved["optimizer"])
    optim.schedule.load_state_dict(saved["scheduler"])
    if optim.amp and saved.get("scaler"):
        optim.scaler.load_state_dict(saved["scaler"])
    set_rng_state(saved["rng"])
    if saved.get("backends") is not None:
        set_backend_flags(saved["backends"])


def _restore(trainer: EpochTrainer, saved: dict[str, Any]) -> None:
    """A resumed run's states from its checkpoint ``saved``."""
    run = trainer.run
    run.net.module.load_state_dict(saved["state_dict"], strict=True)
    restore_carried_state(run.optim, saved)
    trainer.history, trainer.best = list(saved["history"]), saved["best"]
    trainer.last_val = trainer.history[-1]["val_miou"] if trainer.history else None


def write_run_json(run: TrainingRun) -> None:
    """``run.json``, atomically."""
    atomic_write_text(run.out / RUN, json.dumps(run.run_json, indent=2) + "\n", durable=True)


class EpochLog(HookBase[EpochTrainer]):
    """Rank 0's lines: what ``--init`` loaded, what is trained on what, where a resumed run
    goes on; after every epoch its loss, learning rate, validation mIoU, time and speed."""

    def before_train(self, trainer: EpochTrainer) -> None:
        run = trainer.run
        init, data, recipe, procs = run.net.init, run.data, run.recipe, run.procs
        for line in init.lines() if init else []:
            run.say(line)
        splits = data.splits
        where = f"{splits.reader}" + (f", train split {splits.train_split}, val split "
                                      f"{splits.val_split}" if splits.train_split else
                                      ", no splits: validating on the training frames")
        run.say(f"training {run.opts.model} ({run.net.num_classes} classes) on "
                f"{splits.train.name} ({where}): {len(data.frames)} frames, {data.steps} steps "
                f"of {recipe.batch_size} per epoch"
                + (f" ({procs.world} processes x {data.per_process}, {procs.backend})"
                   if procs.world > 1 else "")
                + f"; recipe {recipe.name}, crop {data.crop[0]}x{data.crop[1]}, device "
                  f"{procs.device}" + (", amp" if run.optim.amp else ""))
        if run.start >= recipe.epochs:
            run.say(f"nothing to do: the run has trained all {recipe.epochs} epochs (raise "
                    f"--epochs to continue it)")
        elif run.start:
            run.say(f"resuming after epoch {run.start} of {recipe.epochs}")

    def after_epoch(self, trainer: EpochTrainer) -> None:
        r = trainer.result
        trainer.run.say(
            f"epoch {r.epoch}/{trainer.run.recipe.epochs}  loss {r.loss:.4f}  lr {r.lr:.3g}  "
            f"val mIoU {percent(r.val)}{'  (best)' if r.improved else ''}  "
            f"{r.train_seconds + r.val_seconds:.1f} s  {r.images_per_s} img/s")


class FinalTest(HookBase[EpochTrainer]):
    """After the last epoch (rank 0), or on ``--resume`` of a finished run whose ``best.pt``
    has none yet (a run finished before evsmap made the pass): ``best.pt``'s weights scored on
    the test split, the result in its card and ``run.json``
    (:func:`evsmap.train.evaluate.final_test`)."""

    def after_train(self, trainer: EpochTrainer) -> None:
        run = trainer.run
        if trainer.epoch < run.recipe.epochs or trainer.best is None:
            return
        if not trainer.epochs_run and card_has_test(run.out / BEST):
            return
        trainer.test = final_test(run.opts, run.data.splits, run.net.segmenter, run.out,
                                  device=run.procs.device, bar=run.tty)
        if trainer.test is not None:
            run.run_json.update(trainer.test)
            write_run_json(run)


class Interrupt(HookBase[EpochTrainer]):
    """Ctrl-C (SIGINT) or SIGTERM during training (:mod:`evsmap.interrupt`): the run stops where
    it is - the epoch under way is dropped, the files of the last finished one stay whole (they
    are written by rename), ``checkpoint.pt`` is where ``--resume`` continues - and the
    interruption goes on up as itself, also when it came through compiled code (torch) as
    another exception."""

    def on_exception(self, trainer: EpochTrainer, exc: BaseException) -> None:
        reraise_interruption(exc)


def default_hooks(run: TrainingRun) -> list[HookBase[EpochTrainer]]:
    """The hooks of a run, in order; those that only write or print are rank 0's."""
    main = run.procs.main
    return [ProgressBar(), Evaluator(), *([BestModel()] if main else []), Checkpointer(),
            *([EpochLog()] if main else []), *([FinalTest()] if main else []), Interrupt()]


__all__ = ["BestModel", "Checkpointer", "EpochLog", "Evaluator", "FinalTest", "Interrupt",
           "ProgressBar", "carried_state", "default_hooks", "restore_carried_state",
           "write_run_json"]
