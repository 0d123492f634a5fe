"""Setting up a training run, one piece a function, in the order :func:`set_up` calls them: the
run's folder and the checkpoint to resume (:func:`open_run_folder`), the recipe
(:func:`choose_recipe`) and the network's options (:func:`network_options`), the network
(:func:`build_network`), the data (:func:`open_data`), the device (:func:`place_network`), the
optimiser, schedule, AMP scaler and loss (:func:`build_optimisation`), DDP (:func:`wrap_ddp`),
and what ``run.json`` records (:func:`run_record`). The result, :class:`TrainingRun`, is what
the trainer and its hooks work on; a resumed run's states are restored by the checkpointer hook
(:class:`evsmap.train.hooks.Checkpointer`) when training starts."""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import torch
from torch import nn
from torch.utils.data import DataLoader, DistributedSampler

from evsmap.environment import collect_gpu
from evsmap.errors import EvsmapError
from evsmap.train.checkpoint import CHECKPOINT, load_checkpoint, seed_everything
from evsmap.train.data import EpochKeys, Splits, TrainingFrames, open_splits
from evsmap.train.init import InitReport, load_encoder_weights
from evsmap.train.optim import EpochSchedule, TrainingLoss
from evsmap.train.options import RunOptions
from evsmap.train.processes import Processes
from evsmap.train.recipe import (
    Recipe,
    RecipeError,
    apply_overrides,
    differences,
    load_recipe,
    recipe_from_dict,
)
from evsmap.train.settings import settings_record

RESUMABLE_CHANGES = ("epochs", "workers", "eval_every")
"""Recipe fields a resumed run may change (the others would make it another run)."""
_CARD_DROP = ("weights", "backend")


@dataclass
class Network:
    """The network trained: the registered segmenter, its torch module, its classes and what
    ``--init`` loaded into it."""

    segmenter: Any
    module: nn.Module
    num_classes: int
    init: InitReport | None


@dataclass
class Data:
    """The training data: splits, augmented frames, the sampler and loader of one process, and
    the class names the cards record."""

    splits: Splits
    frames: TrainingFrames
    sampler: EpochKeys
    loader: DataLoader
    steps: int
    per_process: int
    crop: tuple[int, int]
    class_names: tuple[str, ...]


@dataclass
class Optimisation:
    """SGD, the learning rate of each epoch, the AMP scaler (disabled without AMP), the loss."""

    optimizer: torch.optim.Optimizer
    schedule: EpochSchedule
    scaler: torch.amp.GradScaler
    criterion: TrainingLoss
    amp: bool


@dataclass
class TrainingRun:
    """Everything a training run is made of, as :func:`set_up` built it.

    Attributes:
        model: the module, or its ``DistributedDataParallel`` wrapper in a DDP run.
        saved: the checkpoint a resumed run continues (None: a new run).
        start: epochs done before this invocation.
        run_json: what ``run.json`` holds (the hooks add to it).
        tty: rank 0 on a terminal: progress bars.
    """

    opts: RunOptions
    procs: Processes
    recipe: Recipe
    options: dict[str, Any]
    net: Network
    data: Data
    optim: Optimisation
    model: nn.Module
    saved: dict[str, Any] | None
    start: int
    run_json: dict[str, Any]
    tty: bool
    card_options: dict[str, Any] = field(default_factory=dict)

    @property
    def out(self) -> Path:
        return Path(self.opts.out)

    def say(self, text: str) -> None:
        """A line of rank 0's messages (other ranks say nothing)."""
        if self.procs.main:
            self.opts.say(text)

    def card(self, state: dict[str, torch.Tensor], epochs_done: int, val: float | None,
             val_epoch: int | None) -> dict[str, Any]:
        """The card of weights ``state`` after ``epochs_done`` epochs."""
        from evsmap.segmenters.cards import make_card

        splits, recipe = self.data.splits, self.recipe
        return make_card(
            model=self.opts.model, options=self.card_options, num_classes=self.net.num_classes,
            class_names=list(self.data.class_names), state_dict=state,
            dataset=splits.dataset, dataset_name=splits.train.name, reader=splits.reader,
            train_split=splits.train_split, val_split=splits.val_split,
            recipe_name=recipe.name, recipe=recipe.as_dict(), epochs=epochs_done,
            epochs_planned=recipe.epochs, val_miou=val, val_epoch=val_epoch,
            test_miou=val if splits.val_split == "test" else None,
            input_size=list(self.net.segmenter.input_size), world_size=self.procs.world,
            device=self.procs.device.type, amp=self.optim.amp, init=self.run_json["init"],
            created=datetime.now(UTC).isoformat(timespec="seconds"))


def set_up(opts: RunOptions, procs: Processes) -> TrainingRun:
    """Check the request and build the run (nothing is written yet)."""

    def say(text: str) -> None:
        if procs.main:
            opts.say(text)

    saved = open_run_folder(opts)
    recipe, note = choose_recipe(opts, saved["recipe"] if saved else None)
    options = network_options(opts, saved)
    net = build_network(opts, recipe, options, resuming=saved is not None)
    data = open_data(opts, recipe, net, procs)
    place_network(net.module, recipe, procs, channels_last=opts.channels_last,
                  deterministic=opts.deterministic)
    optim = build_optimisation(net.module, recipe, procs, say)
    if saved is not None:
        if saved["run"].get("world_size") != procs.world:
            say(f"note: the run had {saved['run'].get('world_size')} processes, now "
                f"{procs.world}: the continuation will not repeat a straight run")
        if note:
            say(f"note: {note}")
    model = wrap_ddp(net.module, procs)
    return TrainingRun(
        opts=opts, procs=procs, recipe=recipe, options=options, net=net, data=data, optim=optim,
        model=model, saved=saved, start=int(saved["epoch"]) if saved else 0,
        run_json=run_record(opts, recipe, options, net, data, optim, procs, saved),
        tty=procs.main and sys.stderr.isatty(),
        card_options={k: v for k, v in options.items() if k not in _CARD_DROP})


def open_run_folder(opts: RunOptions) -> dict[str, Any] | None:
    """The checkpoint of the run to resume (None for a new run), after checking that ``--out``
    is a folder, holds a checkpoint when resuming and none otherwise, and that the checkpoint
    is a run of the same model with the same options."""
    out = Path(opts.out)
    ckpt_path = out / CHECKPOINT
    if out.exists() and not out.is_dir():
        raise EvsmapError(f"--out {out}: is a file, not a folder (the run's folder: choose "
                          f"another --out)")
    if not opts.resume:
        if ckpt_path.exists():
            raise EvsmapError(f"{out} holds a training run ({CHECKPOINT}): pass --resume to "
                              f"continue it, or choose another --out")
        return None
    if not ckpt_path.is_file():
        raise EvsmapError(f"{ckpt_path}: no checkpoint to resume (start the run without "
                          f"--resume)")
    saved = load_checkpoint(ckpt_path)
    if opts.init is not None:
        raise EvsmapError("--init starts a run; a resumed run continues from its checkpoint")
    if saved["run"]["model"] != opts.model:
        raise EvsmapError(f"{ckpt_path} is a run of {saved['run']['model']}, not {opts.model}")
    if opts.options and dict(opts.options) != saved["run"]["options"]:
        raise EvsmapError(f"{ckpt_path} was trained with options {saved['run']['options']}, "
                          f"not {dict(opts.options)} (leave out -o to keep them)")
    return saved


def choose_recipe(opts: RunOptions, saved: dict[str, Any] | None) -> tuple[Recipe, str | None]:
    """The recipe of this invocation and a note (resumed runs: what changed)."""
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


def network_options(opts: RunOptions, saved: dict[str, Any] | None) -> dict[str, Any]:
    """The segmenter options of the run (a resumed run's unless ``-o`` repeats them)."""
    options = dict(saved["run"]["options"]) if saved and not opts.options else dict(opts.options)
    if options.get("backend", "torch") != "torch":
        raise EvsmapError("training runs the torch backend: leave out -o backend=...")
    if "input_size" in options:
        raise EvsmapError("input_size is not a training option: validation scores what evsmap "
                          "eval scores, at the segmenter's own input size (use --crop and "
                          "--set scale=MIN,MAX for the training resolution)")
    return options


def build_network(opts: RunOptions, recipe: Recipe, options: dict[str, Any], *,
                  resuming: bool) -> Network:
    """The network, seeded: the same initial weights in every process (a resumed run takes its
    weights from the checkpoint, not from a ``-o weights=`` file it started from)."""
    from evsmap.registry import SEGMENTERS

    seed_everything(recipe.seed)
    build = {k: v for k, v in options.items() if not (resuming and k == "weights")}
    segmenter = SEGMENTERS.create(opts.model, **build)
    module = segmenter.module
    if module is None:
        raise EvsmapError(f"{opts.model} is not a network segmenter: there is nothing to train")
    report = load_encoder_weights(module, opts.init) if opts.init is not None else None
    return Network(segmenter, module, int(segmenter.num_classes), report)


def open_data(opts: RunOptions, recipe: Recipe, net: Network, procs: Processes) -> Data:
    """The splits, and this process's share of the recipe's (global) batch of augmented
    frames through a ``DistributedSampler`` (also with one process) and a ``DataLoader``."""
    segmenter, num_classes = net.segmenter, net.num_classes
    splits = open_splits(opts.dataset, reader=opts.reader, reader_options=opts.reader_options,
                         train_split=opts.train_split, val_split=opts.val_split,
                         limit=opts.limit)
    if splits.num_classes is not None and splits.num_classes != num_classes:
        raise EvsmapError(
            f"{opts.model} predicts {num_classes} classes but {splits.train.name!r} is labelled "
            f"with {splits.num_classes}: pass -o num_classes={splits.num_classes}")
    class_names = tuple(splits.class_names) if len(splits.class_names) == num_classes else \
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
    loader = DataLoader(frames, batch_size=per_process, sampler=sampler,
                        num_workers=recipe.workers, drop_last=True,
                        pin_memory=procs.device.type == "cuda",
                        persistent_workers=recipe.workers > 0,
                        generator=torch.Generator().manual_seed(recipe.seed))
    if len(loader) == 0:
        raise EvsmapError(
            f"the training split has {len(frames)} frames, fewer than one batch "
            f"({per_process} per process x {procs.world} processes): lower --batch-size")
    return Data(splits, frames, sampler, loader, len(loader), per_process, crop, class_names)


def place_network(module: nn.Module, recipe: Recipe, procs: Processes, *,
                  channels_last: bool = False, deterministic: bool = False) -> None:
    """The network on this process's device (channels-last where asked); cuDNN autotuning on
    CUDA unless ``deterministic`` (then deterministic algorithms only; torch warns of an
    operation without a deterministic kernel); SyncBatchNorm in a DDP run on CUDA when the
    recipe asks."""
    module.to(procs.device)
    if channels_last:
        module.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
    cuda = procs.device.type == "cuda"
    if deterministic:
        torch.backends.cudnn.benchmark = False
        torch.backends.cudnn.deterministic = True
        torch.use_deterministic_algorithms(True, warn_only=True)
    elif cuda:
        torch.backends.cudnn.benchmark = True
    if procs.world > 1 and cuda and recipe.sync_bn:
        converted = nn.SyncBatchNorm.convert_sync_batchnorm(module)
        if converted is not module:  # pragma: no cover  (a network is never a bare BN)
            raise EvsmapError("cannot convert the network to SyncBatchNorm")


def build_optimisation(module: nn.Module, recipe: Recipe, procs: Processes,
                       say: Callable[[str], None]) -> Optimisation:
    """SGD with the recipe's settings, the epoch schedule, the AMP scaler (AMP on CUDA only: a
    note on the CPU) and the loss."""
    optimizer = torch.optim.SGD(module.parameters(), lr=recipe.lr, momentum=recipe.momentum,
                                weight_decay=recipe.weight_decay, nesterov=recipe.nesterov)
    schedule = EpochSchedule(optimizer, recipe.lr_factor)
    cuda = procs.device.type == "cuda"
    amp = recipe.amp and cuda
    if recipe.amp and not cuda:
        say("note: amp = true has no effect on the CPU (float32 training)")
    scaler = torch.amp.GradScaler(procs.device.type, enabled=amp)
    return Optimisation(optimizer, schedule, scaler, TrainingLoss(recipe), amp)


def wrap_ddp(module: nn.Module, procs: Processes) -> nn.Module:
    """``module`` in a ``DistributedDataParallel`` wrapper in a DDP run, else itself."""
    if procs.world == 1:
        return module
    from torch.nn.parallel import DistributedDataParallel

    return DistributedDataParallel(
        module, device_ids=[procs.device.index] if procs.device.type == "cuda" else None)


def run_record(opts: RunOptions, recipe: Recipe, options: dict[str, Any], net: Network,
               data: Data, optim: Optimisation, procs: Processes,
               saved: dict[str, Any] | None) -> dict[str, Any]:
    """What ``run.json`` says of the run before its first epoch."""
    init = net.init.as_dict() if net.init else (saved or {}).get("run", {}).get("init")
    return {
        "format": "evsmap-train-run", "model": opts.model, "options": options,
        "recipe_name": recipe.name, "recipe_overrides": dict(opts.overrides),
        **data.splits.describe(), "world_size": procs.world, "backend": procs.backend,
        "device": procs.device.type, "batch_per_process": data.per_process,
        "steps_per_epoch": data.steps, "crop": list(data.crop),
        "input_size": list(net.segmenter.input_size), "amp": optim.amp, "init": init,
        "channels_last": opts.channels_last, "deterministic": opts.deterministic,
        "threads": torch.get_num_threads(), "gpu": collect_gpu(procs.device),
        "settings": settings_record(opts, procs.device.type, torch.get_num_threads()),
    }


__all__ = ["RESUMABLE_CHANGES", "Data", "Network", "Optimisation", "TrainingRun",
           "build_network", "build_optimisation", "choose_recipe", "network_options",
           "open_data", "open_run_folder", "place_network", "run_record", "set_up", "wrap_ddp"]
