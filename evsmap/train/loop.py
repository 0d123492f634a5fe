"""The training loop of ``evsmap train``: one process, or DDP under ``torchrun``.

* **Model**: the registered segmenter's network (``SEGMENTERS.create(name, **options)``); in
  training mode it returns its side outputs too, and every head gets the hybrid loss of eq. 1
  (:class:`~evsmap.losses.HybridLoss`, void ignored) against the labels resized to its size
  (:class:`~evsmap.losses.MultiScaleLoss`), the main head with weight 1 and each side head with
  the recipe's ``side_weight``.
* **Optimiser and schedule**: SGD; the learning rate of epoch ``e`` is ``lr * recipe.lr_factor(e)``
  (:func:`evsmap.train.recipe.poly_factor`), set at the start of the epoch.
* **Data**: :class:`~evsmap.train.data.TrainingFrames` through a ``DistributedSampler`` (shuffled
  with ``seed + epoch``, also with one process) and a ``DataLoader``; the recipe's batch is the
  global batch, split evenly over the processes.
* **Determinism**: every epoch starts by seeding torch, numpy and Python from (seed, epoch,
  rank), and samples draw their augmentation from (seed, epoch, frame); so a run stopped after
  any epoch and resumed from its checkpoint repeats the straight run bit for bit on the CPU.
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
  (:func:`final_test`).
"""

from __future__ import annotations

import csv
import io
import json
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist
from torch import nn
from tqdm import tqdm

from evsmap.errors import EvsmapError
from evsmap.fileio import atomic_write_text
from evsmap.losses import HybridLoss, MultiScaleLoss
from evsmap.train.checkpoint import (
    BEST,
    CHECKPOINT,
    FORMAT,
    LAST,
    LOG,
    RUN,
    VERSION,
    atomic_save,
    cpu_state,
    derived_seed,
    load_checkpoint,
    rng_state,
    save_weights,
    seed_everything,
    set_rng_state,
)
from evsmap.train.evaluate import (
    card_has_test,
    final_test,
    open_test_split,
    predict_classes,
    validate,
)
from evsmap.train.processes import Processes, start_processes
from evsmap.train.recipe import (
    Recipe,
    RecipeError,
    apply_overrides,
    differences,
    load_recipe,
    recipe_from_dict,
)

RESUMABLE_CHANGES = ("epochs", "workers", "eval_every")
"""Recipe fields a resumed run may change (the others would make it another run)."""
LOG_COLUMNS = ("epoch", "lr", "loss", "val_miou", "train_seconds", "val_seconds", "seconds",
               "images", "images_per_s")
_CARD_DROP = ("weights", "backend")


@dataclass
class RunOptions:
    """What ``evsmap train`` was asked to do (see its ``--help``).

    Attributes:
        model: registered segmenter name.
        dataset: folder, prepared dataset name or path-less reader name.
        out: the run's folder.
        recipe: shipped recipe name or TOML file; None: ``paper`` (or, resuming, the
            checkpoint's recipe).
        overrides: recipe fields set on the command line.
        options: segmenter options (``-o``).
        reader, reader_options: as ``evsmap eval``'s.
        train_split, val_split: splits of readers that have them.
        limit: first N frames of each split.
        device: ``cpu``, ``cuda`` or ``cuda:N``; None: CUDA when available.
        resume: continue the run in ``out`` from its checkpoint.
        init: encoder weights to start from.
        stop_after: stop after this many epochs of this invocation.
        messages: where rank 0 writes its lines (default stdout).
    """

    model: str
    dataset: str
    out: Path
    recipe: str | None = None
    overrides: dict[str, Any] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)
    reader: str | None = None
    reader_options: list[tuple[str, object]] = field(default_factory=list)
    train_split: str | None = None
    val_split: str | None = None
    limit: int | None = None
    device: str | None = None
    resume: bool = False
    init: Path | None = None
    stop_after: int | None = None
    messages: Any = None


# -- schedule and loss ----------------------------------------------------------------------------

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


# -- the run --------------------------------------------------------------------------------------

def _batches(batches):
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


def _say(procs: Processes, opts: RunOptions, text: str) -> None:
    if procs.main:
        print(text, file=opts.messages or sys.stdout, flush=True)


def _recipe(opts: RunOptions, saved: dict[str, Any] | None) -> tuple[Recipe, str | None]:
    """The recipe of this invocation and a note (resumed runs)."""
    if saved is None:
        return apply_overrides(load_recipe(opts.recipe or "paper"), opts.overrides), None
    before = recipe_from_dict(saved, where="the checkpoint's recipe")
    base = load_recipe(opts.recipe) if opts.recipe else before
    recipe = apply_overrides(base, opts.overrides)
    changed = differences(before, recipe)
    refused = [k for k in changed if k not in RESUMABLE_CHANGES]
    if refused:
        key = refused[0]
        raise RecipeError(
            f"a resumed run keeps its recipe: {key} is {changed[key][0]!r} in the checkpoint, "
            f"{changed[key][1]!r} here (only {', '.join(RESUMABLE_CHANGES)} may change)")
    note = None
    if changed:
        note = "recipe changed on resume: " + ", ".join(
            f"{k} {a!r} -> {b!r}" for k, (a, b) in changed.items())
    return recipe, note


def _csv(rows: list[dict[str, Any]]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=LOG_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if row.get(k) is None else row[k]) for k in LOG_COLUMNS})
    return buf.getvalue()


def _pct(x: float | None) -> str:
    return "n/a" if x is None else f"{100 * x:.2f} %"


def _params_sha256(module: nn.Module) -> str:
    from evsmap.segmenters.cards import tensor_sha256

    return tensor_sha256(dict(module.named_parameters()))


def train(opts: RunOptions) -> dict[str, Any]:
    """Run (or resume) a training run; returns a summary (rank 0's; other ranks' are equal
    but for the files they did not write)."""
    procs = start_processes(opts.device)
    try:
        return _train(opts, procs)
    finally:
        if procs.started and dist.is_initialized():
            dist.destroy_process_group()


def _train(opts: RunOptions, procs: Processes) -> dict[str, Any]:
    from torch.utils.data import DataLoader, DistributedSampler

    from evsmap.metrics import ConfusionMatrix
    from evsmap.registry import SEGMENTERS
    from evsmap.segmenters.cards import make_card
    from evsmap.train.data import EpochKeys, TrainingFrames, open_splits
    from evsmap.train.init import load_encoder_weights

    out = Path(opts.out)
    ckpt_path = out / CHECKPOINT
    saved: dict[str, Any] | None = None
    if out.exists() and not out.is_dir():
        raise EvsmapError(f"--out {out}: is a file, not a folder (the run's folder: choose "
                          f"another --out)")
    if opts.resume:
        if not ckpt_path.is_file():
            raise EvsmapError(f"{ckpt_path}: no checkpoint to resume (start the run without "
                              f"--resume)")
        saved = load_checkpoint(ckpt_path)
        if opts.init is not None:
            raise EvsmapError("--init starts a run; a resumed run continues from its checkpoint")
        if saved["run"]["model"] != opts.model:
            raise EvsmapError(f"{ckpt_path} is a run of {saved['run']['model']}, not "
                              f"{opts.model}")
        if opts.options and dict(opts.options) != saved["run"]["options"]:
            raise EvsmapError(f"{ckpt_path} was trained with options {saved['run']['options']}, "
                              f"not {dict(opts.options)} (leave out -o to keep them)")
    elif ckpt_path.exists():
        raise EvsmapError(f"{out} holds a training run ({CHECKPOINT}): pass --resume to continue "
                          f"it, or choose another --out")
    recipe, note = _recipe(opts, saved["recipe"] if saved else None)
    options = dict(saved["run"]["options"]) if saved and not opts.options else dict(opts.options)
    if options.get("backend", "torch") != "torch":
        raise EvsmapError("training runs the torch backend: leave out -o backend=...")
    if "input_size" in options:
        raise EvsmapError("input_size is not a training option: validation scores what evsmap "
                          "eval scores, at the segmenter's own input size (use --crop and "
                          "--set scale=MIN,MAX for the training resolution)")

    # the network, seeded: the same initial weights in every process (a resumed run takes its
    # weights from the checkpoint, not from a -o weights= file it started from)
    seed_everything(recipe.seed)
    build = {k: v for k, v in options.items() if not (saved and k == "weights")}
    segmenter = SEGMENTERS.create(opts.model, **build)
    module = segmenter.module
    if module is None:
        raise EvsmapError(f"{opts.model} is not a network segmenter: there is nothing to train")
    num_classes = int(segmenter.num_classes)
    report = load_encoder_weights(module, opts.init) if opts.init is not None else None

    splits = open_splits(opts.dataset, reader=opts.reader, reader_options=opts.reader_options,
                         train_split=opts.train_split, val_split=opts.val_split,
                         limit=opts.limit)
    if splits.num_classes is not None and splits.num_classes != num_classes:
        raise EvsmapError(
            f"{opts.model} predicts {num_classes} classes but {splits.train.name!r} is labelled "
            f"with {splits.num_classes}: pass -o num_classes={splits.num_classes}")
    class_names = splits.class_names if len(splits.class_names) == num_classes else \
        tuple(segmenter.class_names)

    if recipe.batch_size % procs.world:
        raise EvsmapError(f"batch_size {recipe.batch_size} does not split over {procs.world} "
                          f"processes: use a multiple of {procs.world}")
    per_process = recipe.batch_size // procs.world
    crop = recipe.crop_size(segmenter.input_size)
    frames = TrainingFrames(splits.train, normalization=segmenter.normalization,
                            uses_depth=segmenter.uses_depth, input_size=segmenter.input_size,
                            crop=crop, scale=recipe.scale, flip=recipe.flip, seed=recipe.seed,
                            num_classes=num_classes)
    sampler = EpochKeys(DistributedSampler(frames, num_replicas=procs.world, rank=procs.rank,
                                           shuffle=True, seed=recipe.seed, drop_last=True))
    cuda = procs.device.type == "cuda"
    loader = DataLoader(frames, batch_size=per_process, sampler=sampler,
                        num_workers=recipe.workers, drop_last=True, pin_memory=cuda,
                        persistent_workers=recipe.workers > 0,
                        generator=torch.Generator().manual_seed(recipe.seed))
    steps = len(loader)
    if steps == 0:
        raise EvsmapError(
            f"the training split has {len(frames)} frames, fewer than one batch "
            f"({per_process} per process x {procs.world} processes): lower --batch-size")

    module.to(procs.device)
    if cuda:
        torch.backends.cudnn.benchmark = True
    if procs.world > 1 and cuda and recipe.sync_bn:
        converted = nn.SyncBatchNorm.convert_sync_batchnorm(module)
        if converted is not module:  # pragma: no cover  (a network is never a bare BN)
            raise EvsmapError("cannot convert the network to SyncBatchNorm")
    optimizer = torch.optim.SGD(module.parameters(), lr=recipe.lr, momentum=recipe.momentum,
                                weight_decay=recipe.weight_decay, nesterov=recipe.nesterov)
    schedule = EpochSchedule(optimizer, recipe.lr_factor)
    amp = recipe.amp and cuda
    if recipe.amp and not cuda:
        _say(procs, opts, "note: amp = true has no effect on the CPU (float32 training)")
    scaler = torch.amp.GradScaler(procs.device.type, enabled=amp)
    criterion = TrainingLoss(recipe)

    start, history, best = 0, [], None
    if saved is not None:
        module.load_state_dict(saved["state_dict"], strict=True)
        optimizer.load_state_dict(saved["optimizer"])
        schedule.load_state_dict(saved["scheduler"])
        if amp and saved.get("scaler"):
            scaler.load_state_dict(saved["scaler"])
        set_rng_state(saved["rng"])
        start, history, best = int(saved["epoch"]), list(saved["history"]), saved["best"]
        if saved["run"].get("world_size") != procs.world:
            _say(procs, opts, f"note: the run had {saved['run'].get('world_size')} processes, now "
                        f"{procs.world}: the continuation will not repeat a straight run")
        if note:
            _say(procs, opts, f"note: {note}")

    model: nn.Module = module
    if procs.world > 1:
        from torch.nn.parallel import DistributedDataParallel

        model = DistributedDataParallel(module, device_ids=[procs.device.index] if cuda else None)

    run = {
        "format": "evsmap-train-run", "model": opts.model, "options": options,
        "recipe_name": recipe.name, "recipe_overrides": dict(opts.overrides),
        **splits.describe(), "world_size": procs.world, "backend": procs.backend,
        "device": procs.device.type, "batch_per_process": per_process,
        "steps_per_epoch": steps, "crop": list(crop), "input_size": list(segmenter.input_size),
        "amp": amp, "init": report.as_dict() if report else (saved or {}).get("run", {}).get(
            "init"),
    }
    card_options = {k: v for k, v in options.items() if k not in _CARD_DROP}

    def card(state: dict[str, torch.Tensor], epochs_done: int, val: float | None,
             val_epoch: int | None) -> dict[str, Any]:
        return make_card(
            model=opts.model, options=card_options, num_classes=num_classes,
            class_names=list(class_names), state_dict=state,
            dataset=splits.dataset, dataset_name=splits.train.name, reader=splits.reader,
            train_split=splits.train_split, val_split=splits.val_split,
            recipe_name=recipe.name, recipe=recipe.as_dict(), epochs=epochs_done,
            epochs_planned=recipe.epochs, val_miou=val, val_epoch=val_epoch,
            test_miou=val if splits.val_split == "test" else None,
            input_size=list(segmenter.input_size), world_size=procs.world,
            device=procs.device.type, amp=amp, init=run["init"],
            created=datetime.now(UTC).isoformat(timespec="seconds"))

    if procs.main:
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:  # a file on the way, no permission: one line, not a traceback
            raise EvsmapError(f"--out {out}: cannot create the run's folder "
                              f"({exc.strerror or type(exc).__name__})") from None
        for line in report.lines() if report else []:
            _say(procs, opts, line)
        where = f"{splits.reader}" + (f", train split {splits.train_split}, val split "
                                      f"{splits.val_split}" if splits.train_split else
                                      ", no splits: validating on the training frames")
        _say(procs, opts,
             f"training {opts.model} ({num_classes} classes) on {splits.train.name} ({where}): "
             f"{len(frames)} frames, {steps} steps of {recipe.batch_size} per epoch"
             + (f" ({procs.world} processes x {per_process}, {procs.backend})"
                if procs.world > 1 else "")
             + f"; recipe {recipe.name}, crop {crop[0]}x{crop[1]}, device {procs.device}"
             + (", amp" if amp else ""))
        if start >= recipe.epochs:
            _say(procs, opts, f"nothing to do: the run has trained all {recipe.epochs} epochs "
                              f"(raise --epochs to continue it)")
        elif start:
            _say(procs, opts, f"resuming after epoch {start} of {recipe.epochs}")

    tty = procs.main and sys.stderr.isatty()
    done_here = 0
    last_val: float | None = history[-1]["val_miou"] if history else None
    for epoch in range(start, recipe.epochs):
        if opts.stop_after is not None and done_here >= opts.stop_after:
            break
        lr = schedule.start(epoch)
        sampler.set_epoch(epoch)
        module.train()
        batches = iter(loader)
        seed_everything(derived_seed(recipe.seed, epoch, procs.rank))
        t0 = time.perf_counter()
        loss_sum = torch.zeros((), dtype=torch.float64, device=procs.device)
        images = 0
        seen: list[int] = []
        bar = tqdm(total=steps, desc=f"epoch {epoch + 1}/{recipe.epochs}", unit="step",
                   leave=False, file=sys.stderr, disable=not tty)
        for batch in _batches(batches):
            labels = batch["labels"].to(procs.device, non_blocking=True)
            inputs = [batch["rgb"].to(procs.device, non_blocking=True)]
            if "depth" in batch:
                inputs.append(batch["depth"].to(procs.device, non_blocking=True))
            with torch.autocast(procs.device.type, dtype=torch.float16, enabled=amp):
                outputs = model(*inputs)
            loss = criterion(outputs, labels)
            optimizer.zero_grad(set_to_none=True)
            scaler.scale(loss).backward()
            scaler.step(optimizer)
            scaler.update()
            loss_sum += loss.detach().double()
            images += int(labels.shape[0])
            seen.extend(int(i) for i in batch["index"])
            if tty:
                bar.update(1)
                bar.set_postfix(loss=f"{loss.item():.4f}", lr=f"{lr:.2e}")
        bar.close()
        if cuda:
            torch.cuda.synchronize(procs.device)
        train_seconds = time.perf_counter() - t0
        totals = torch.tensor([float(loss_sum), float(steps), float(images)],
                              dtype=torch.float64,
                              device=procs.device if procs.backend == "nccl" else "cpu")
        totals = procs.sum_(totals).cpu()
        mean_loss = float(totals[0] / totals[1])
        all_images = int(totals[2])
        if not math.isfinite(mean_loss):
            raise EvsmapError(f"the loss is {mean_loss} after epoch {epoch + 1}: lower the "
                              f"learning rate (--lr) or check the labels")
        ranks = None
        if procs.world > 1:
            ranks = procs.gather({"rank": procs.rank, "images": images, "indices": seen,
                                  "params_sha256": _params_sha256(module)})

        val = None
        val_seconds = 0.0
        last = epoch + 1 == recipe.epochs
        if recipe.eval_every and ((epoch + 1) % recipe.eval_every == 0 or last):
            t1 = time.perf_counter()
            if procs.world > 1:  # rank 0's BatchNorm statistics, the ones saved
                for buffer in module.buffers():
                    dist.broadcast(buffer, src=0)
            module.eval()
            counts = validate(segmenter, splits.val, procs, bar=tty)
            val = ConfusionMatrix.from_matrix(counts).result().miou
            val = None if math.isnan(val) else float(val)
            val_seconds = time.perf_counter() - t1
            last_val = val
        done_here += 1
        if not procs.main:
            continue
        row = {"epoch": epoch + 1, "lr": lr, "loss": mean_loss, "val_miou": val,
               "train_seconds": round(train_seconds, 3), "val_seconds": round(val_seconds, 3),
               "seconds": round(train_seconds + val_seconds, 3), "images": all_images,
               "images_per_s": round(all_images / train_seconds, 3) if train_seconds else None}
        history.append(row)
        state = cpu_state(module.state_dict())
        improved = val is not None and (best is None or val > best["val_miou"])
        if improved:
            best = {"epoch": epoch + 1, "val_miou": val}
            save_weights(out / BEST, state, card(state, epoch + 1, val, epoch + 1))
        val_epoch = epoch + 1 if val is not None else None
        last_card = card(state, epoch + 1, val, val_epoch)
        save_weights(out / LAST, state, last_card)
        atomic_write_text(out / LOG, _csv(history), durable=True)
        run.update(epochs_done=epoch + 1, best=best, ranks=ranks,
                   evsmap_version=last_card["evsmap_version"],
                   git_commit=last_card["git_commit"])
        atomic_write_text(out / RUN, json.dumps(run, indent=2) + "\n", durable=True)
        atomic_save({
            "format": FORMAT, "version": VERSION, "state_dict": state, "card": last_card,
            "optimizer": optimizer.state_dict(), "scheduler": schedule.state_dict(),
            "scaler": scaler.state_dict() if amp else None, "rng": rng_state(),
            "epoch": epoch + 1, "recipe": recipe.as_dict(), "run": run, "history": history,
            "best": best,
        }, ckpt_path)
        _say(procs, opts, f"epoch {epoch + 1}/{recipe.epochs}  loss {mean_loss:.4f}  lr {lr:.3g}  "
                          f"val mIoU {_pct(val)}{'  (best)' if improved else ''}  "
                          f"{train_seconds + val_seconds:.1f} s  {row['images_per_s']} img/s")

    epochs_done = start + done_here
    test = None
    # the final test pass: after the last epoch, or on --resume of a finished run whose best.pt
    # has none yet (a run finished before evsmap made the pass)
    if procs.main and epochs_done >= recipe.epochs and best is not None and (
            done_here or not card_has_test(out / BEST)):
        test = final_test(opts, splits, segmenter, out, device=procs.device, bar=tty)
        if test is not None:
            run.update(test)
            atomic_write_text(out / RUN, json.dumps(run, indent=2) + "\n", durable=True)
    summary = {
        "out": str(out), "model": opts.model, "epochs": epochs_done,
        "epochs_planned": recipe.epochs, "finished": epochs_done >= recipe.epochs,
        "best_epoch": best["epoch"] if best else None,
        "best_val_miou": best["val_miou"] if best else None, "last_val_miou": last_val,
        "test_miou": (test or {}).get("test_miou"), "world_size": procs.world,
        "files": {name: str(out / name) for name in (CHECKPOINT, LAST, BEST, LOG, RUN)
                  if (out / name).exists()},
    }
    if procs.world > 1:
        dist.barrier()
    return summary


__all__ = ["EpochSchedule", "Processes", "RunOptions", "TrainingLoss", "final_test",
           "open_test_split", "predict_classes", "start_processes", "train", "validate"]
