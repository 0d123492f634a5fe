"""Training data: any evsmap labelled reader as a torch dataset, fed to the network exactly as
:class:`~evsmap.segmenters.network.NetworkSegmenter` feeds it at inference, with random scale,
crop and flip.

One sample (:class:`TrainingFrames`) is built in this order:

1. ``s ~ U(scale_min, scale_max)``; the frame goes through
   :func:`~evsmap.segmenters.network.network_inputs` - the inference preprocessing: RGB to
   [0, 1], bilinear resize, per-channel standardisation; depth nearest-resized and standardised,
   invalid depth 0 - at ``round(s * input_size)``: the scale is relative to the size
   ``evsmap eval`` resizes frames to, so ``s = 1`` is what the network sees at test time. The
   labels are resized by nearest neighbour (void stays void) to the same size.
2. Padding to at least the crop size at the bottom and right: RGB and depth 0 (the mean colour
   and the mean depth after standardisation), labels void (ignored by the loss).
3. A crop of the crop size at a uniformly random position.
4. A horizontal flip with probability ``flip``.

The random numbers of a sample come from ``numpy.random.default_rng([seed, epoch, index])``:
the same (seed, epoch, frame) gives the same sample in any process, worker or order, which is
what makes a resumed or distributed run repeat a straight one. The sampler therefore hands the
dataset ``(epoch, index)`` keys (:class:`EpochKeys`). Everything is vectorised (whole-image torch
ops); no per-pixel Python.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import Dataset, Sampler

from evsmap.data import VOID, Sequence
from evsmap.errors import EvsmapError, InvalidDataError
from evsmap.losses import downsample_labels
from evsmap.segmenters.network import Normalization, network_inputs


def scaled_size(size: tuple[int, int], scale: float) -> tuple[int, int]:
    """``round(scale * size)`` per side, at least 1 pixel."""
    return max(1, int(round(size[0] * scale))), max(1, int(round(size[1] * scale)))


class TrainingFrames(Dataset):
    """Augmented training samples from a labelled sequence.

    Args:
        sequence: an evsmap sequence whose frames have RGB, depth and labels.
        normalization: the network's input normalisation.
        uses_depth: whether samples carry depth.
        input_size: the network's input size (H, W); scales are relative to it.
        crop: the crop (H, W) every sample has.
        scale: (min, max) of the random scale.
        flip: probability of a horizontal flip.
        seed: the run's seed.
        num_classes: labels must be class ids below it or void.

    Items are dicts ``{"rgb": (3, H, W) float32, "labels": (H, W) int64}`` plus
    ``"depth": (1, H, W)`` when ``uses_depth``, and ``"index"``; the key is ``(epoch, index)``
    (a bare index means epoch 0).
    """

    def __init__(self, sequence: Sequence, *, normalization: Normalization, uses_depth: bool,
                 input_size: tuple[int, int], crop: tuple[int, int],
                 scale: tuple[float, float] = (1.0, 1.0), flip: float = 0.0, seed: int = 0,
                 num_classes: int) -> None:
        self.sequence = sequence
        self.normalization = normalization
        self.uses_depth = bool(uses_depth)
        self.input_size = (int(input_size[0]), int(input_size[1]))
        self.crop = (int(crop[0]), int(crop[1]))
        self.scale = (float(scale[0]), float(scale[1]))
        self.flip = float(flip)
        self.seed = int(seed)
        self.num_classes = int(num_classes)

    def __len__(self) -> int:
        return len(self.sequence)

    def draws(self, epoch: int, index: int) -> dict[str, float | int | bool]:
        """The random choices of one sample, before they meet its size: scale and the crop
        position as fractions in [0, 1) of the free range."""
        rng = np.random.default_rng([self.seed, int(epoch), int(index)])
        lo, hi = self.scale
        u = rng.random(4)
        return {"scale": lo + (hi - lo) * float(u[0]), "y": float(u[1]), "x": float(u[2]),
                "flip": bool(u[3] < self.flip)}

    def __getitem__(self, key: int | tuple[int, int]) -> dict[str, torch.Tensor]:
        epoch, index = key if isinstance(key, tuple) else (0, key)
        frame = self.sequence.frame(index)
        if frame.labels is None:
            raise InvalidDataError(f"frame {frame.name or index!r} of {self.sequence.name!r} "
                                   f"has no labels: training needs a labelled dataset")
        frame.require_images("training")
        d = self.draws(epoch, index)
        size = scaled_size(self.input_size, d["scale"])
        rgb, depth = frame.rgb, None
        assert rgb is not None  # an RGB-D frame (require_images)
        if self.uses_depth:
            assert frame.depth is not None
            depth = self.normalization.encode_depth(frame.depth, frame)
        inputs = network_inputs(rgb, depth, self.normalization, size)
        labels = torch.from_numpy(np.asarray(frame.labels, dtype=np.uint8).astype(np.int64))
        bad = (labels >= self.num_classes) & (labels != VOID)
        if bool(bad.any()):
            raise InvalidDataError(
                f"frame {frame.name or index!r} of {self.sequence.name!r} has label "
                f"{int(labels[bad].max())}, outside 0..{self.num_classes - 1} (void {VOID}): "
                f"does the network have the dataset's classes (-o num_classes=N)?")
        labels = downsample_labels(labels[None], size)  # nearest, void stays void
        tensors = [*inputs, labels[:, None]]  # every tensor (1, C, h, w)
        ch, cw = self.crop
        pad_h, pad_w = max(ch - size[0], 0), max(cw - size[1], 0)
        if pad_h or pad_w:
            fills = [0.0] * len(inputs) + [VOID]
            tensors = [F.pad(t, (0, pad_w, 0, pad_h), value=v) for t, v in zip(tensors, fills,
                                                                                 strict=True)]
        h, w = tensors[0].shape[-2:]
        y0 = int(d["y"] * (h - ch + 1))
        x0 = int(d["x"] * (w - cw + 1))
        tensors = [t[..., y0:y0 + ch, x0:x0 + cw] for t in tensors]
        if d["flip"]:
            tensors = [t.flip(-1) for t in tensors]
        item = {"rgb": tensors[0][0].contiguous(), "labels": tensors[-1][0, 0].contiguous(),
                "index": torch.tensor(index)}
        if self.uses_depth:
            item["depth"] = tensors[1][0].contiguous()
        return item


class EpochKeys(Sampler):
    """Wraps an index sampler (a ``DistributedSampler``) so it yields ``(epoch, index)`` keys:
    the dataset draws a sample's random numbers from them (see the module notes)."""

    def __init__(self, sampler: Sampler) -> None:
        self.sampler = sampler
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)
        if hasattr(self.sampler, "set_epoch"):
            self.sampler.set_epoch(self.epoch)

    def __iter__(self) -> Iterator[tuple[int, int]]:
        return ((self.epoch, int(i)) for i in self.sampler)

    def __len__(self) -> int:
        return len(self.sampler)  # type: ignore[arg-type]


class FirstFrames(Sequence):
    """The first ``limit`` frames of a sequence (for readers that take no ``limit``)."""

    def __init__(self, sequence: Sequence, limit: int) -> None:
        super().__init__(sequence.name, sequence.intrinsics, sequence.meta)
        self.sequence = sequence
        self.limit = min(int(limit), len(sequence))
        self.class_names = sequence.class_names
        self.num_classes = sequence.num_classes

    def __len__(self) -> int:
        return self.limit

    def frame(self, index: int):
        return self.sequence.frame(index)


@dataclass
class Splits:
    """The sequences a run trains and validates on.

    Attributes:
        train: training frames.
        val: validation frames (the training frames themselves for a reader without splits).
        reader: the reader's registered name.
        dataset: the folder (or reader name) read.
        train_split: the training split, None for a reader without splits.
        val_split: the validation split, None for a reader without splits.
        num_classes: the dataset's class count where the reader says it, else None.
        class_names: the dataset's class names where the reader says them.
    """

    train: Sequence
    val: Sequence
    reader: str
    dataset: str
    train_split: str | None
    val_split: str | None
    num_classes: int | None
    class_names: tuple[str, ...]

    def describe(self) -> dict[str, Any]:
        return {"dataset": self.dataset, "dataset_name": self.train.name, "reader": self.reader,
                "train_split": self.train_split, "val_split": self.val_split,
                "train_frames": len(self.train), "val_frames": len(self.val)}


VALIDATION_SPLIT = {"cityscapes": "val", "synthrooms": "val"}
"""The split a training run validates on (and picks ``best.pt`` by) when none is named: the
dataset's labelled validation split where it has one; elsewhere ``test``."""


def open_splits(dataset: str, *, reader: str | None = None,
                reader_options: list[tuple[str, object]] | None = None,
                train_split: str | None = None, val_split: str | None = None,
                limit: int | None = None) -> Splits:
    """Open the training and validation splits of ``dataset`` (a folder, a prepared dataset's
    name or a reader that needs no path), found and opened as ``evsmap eval`` opens it.

    Readers with splits: ``train_split`` (default ``train``) and ``val_split`` (default
    :data:`VALIDATION_SPLIT`: ``val`` where the dataset has a labelled validation split -
    Cityscapes, synthrooms - else ``test``, as the paper validates NYUv2 and SUN RGB-D). Readers
    without splits: both are every frame of the sequence, and naming a split is an error.
    ``limit`` keeps the first N frames of each.
    """
    from evsmap.datasets.lookup import dataset_classes, find_dataset, reader_name
    from evsmap.readers.detect import open_sequence
    from evsmap.registry import READERS

    text, named = find_dataset(str(dataset), reader)
    name = reader_name(text, named)
    takes = READERS.get(name).takes
    config = dict(reader_options or [])
    if "split" in config:
        raise EvsmapError("choose the splits with --train-split / --val-split, not -r split=")
    splits: tuple[str | None, str | None]
    if takes.split:
        splits = (train_split or "train", val_split or VALIDATION_SPLIT.get(name, "test"))
    else:
        given = train_split or val_split
        if given is not None:
            raise EvsmapError(f"reader {name!r} has no splits: leave out --train-split and "
                              f"--val-split (it trains and validates on every frame)")
        splits = (None, None)
    if limit is not None and takes.limit:
        config["limit"] = limit

    def one(split: str | None) -> Sequence:
        options = dict(config, **({"split": split} if split is not None else {}))
        sequence = open_sequence(text, named, list(options.items()))
        if limit is not None and not takes.limit:
            sequence = FirstFrames(sequence, limit)
        return sequence

    train = one(splits[0])
    val = train if splits[1] is None else one(splits[1])
    if len(train) == 0:
        raise EvsmapError(f"{train.name!r} ({name}, split {splits[0]}) has no frames")
    count, names = dataset_classes(train)
    return Splits(train=train, val=val, reader=name, dataset=text, train_split=splits[0],
                  val_split=splits[1], num_classes=count, class_names=names)


__all__ = ["EpochKeys", "FirstFrames", "Splits", "TrainingFrames", "open_splits",
           "scaled_size"]
