"""Scoring a network during and after training: validation every ``eval_every`` epochs (the
frames shared by the processes, their confusion matrices summed) and the final test pass of
``best.pt``'s weights, whose mIoU goes into its card. Frames are predicted exactly as
``evsmap eval`` predicts them, through the same loop
(:func:`evsmap.measure.engine.run_segmentation`); on a GPU the same computation with the
tensors moved there."""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from evsmap.data import SemanticObservation
from evsmap.errors import EvsmapError
from evsmap.interfaces import Segmenter
from evsmap.train.checkpoint import BEST, save_weights
from evsmap.train.data import Splits
from evsmap.train.options import RunOptions
from evsmap.train.processes import Processes


def percent(x: float | None) -> str:
    """An mIoU as the run's messages print it (``n/a`` when there is none)."""
    return "n/a" if x is None else f"{100 * x:.2f} %"


def _top_on(device: torch.device, segmenter, frame, k: int):
    """The ``k`` most likely classes of every pixel of ``frame`` (``torch.topk``'s values and
    indices, on ``device``): what ``predict`` computes on the CPU - preprocess, network,
    bilinear resize to the frame, softmax - with the tensors moved to ``device``."""
    inputs = tuple(t.to(device) for t in segmenter.preprocess(frame))
    with torch.inference_mode():
        logits = segmenter.module(*inputs)
        h, w = frame.rgb.shape[:2]
        if tuple(logits.shape[-2:]) != (h, w):
            logits = F.interpolate(logits, size=(h, w), mode="bilinear", align_corners=False)
        scores = logits[0].float().permute(1, 2, 0).contiguous()
        return torch.softmax(scores, dim=-1).topk(k, dim=-1)


def predict_classes(segmenter, frame, device: torch.device) -> np.ndarray:
    """The class map ``evsmap eval`` scores for ``frame``: ``segmenter.predict(frame).argmax``
    on the CPU; on a GPU the same steps (preprocess, network, bilinear resize to the frame,
    most likely class) with the tensors moved there."""
    k = min(3, int(segmenter.num_classes))
    if device.type == "cpu":
        return segmenter.predict(frame, k=k).argmax
    classes = _top_on(device, segmenter, frame, k).indices[..., 0]
    return classes.to(torch.int16).cpu().numpy()


class _Validating(Segmenter):
    """``segmenter`` predicting as :func:`predict_classes` does (on ``device``), for the
    measurement engine: the top classes and probabilities of each pixel."""

    def __init__(self, segmenter, device: torch.device) -> None:
        self.inner, self.device = segmenter, device
        self.num_classes = int(segmenter.num_classes)
        self.class_names = tuple(segmenter.class_names or ())

    @property
    def module(self):
        return self.inner.module

    def predict(self, frame, *, k: int = 3) -> SemanticObservation:
        k = min(k, self.num_classes)
        if self.device.type == "cpu":
            return self.inner.predict(frame, k=k)
        top = _top_on(self.device, self.inner, frame, k)
        return SemanticObservation(classes=top.indices.to(torch.int16).cpu().numpy(),
                                   probs=top.values.cpu().numpy(), num_classes=self.num_classes)


def validate(segmenter, sequence, procs: Processes, *, bar: bool = False) -> np.ndarray:
    """The confusion matrix of the network on ``sequence``, summed over the processes (each
    predicts frames ``rank, rank + world, ...``), through the measurement engine's
    segmentation loop (:func:`evsmap.measure.engine.run_segmentation`, as ``evsmap eval``)."""
    from evsmap.measure.engine import run_segmentation
    from evsmap.measure.evaluators import ConfusionEvaluator

    n = int(segmenter.num_classes)
    indices = list(range(procs.rank, len(sequence), procs.world))
    confusion = ConfusionEvaluator(num_classes=n, source=sequence.name,
                                   needs="validation needs a labelled split")
    run_segmentation(sequence, _Validating(segmenter, procs.device), indices=indices,
                     evaluators=[confusion],
                     progress=lambda it: tqdm(it, desc="validating", unit="frame", leave=False,
                                              file=sys.stderr, disable=not bar))
    counts = torch.from_numpy(confusion.matrix.matrix.copy()).to(
        procs.device if procs.backend == "nccl" else "cpu")
    return procs.sum_(counts).cpu().numpy()


# -- the final test pass --------------------------------------------------------------------------

TEST_SPLIT = "test"


def open_test_split(opts: RunOptions, splits: Splits) -> tuple[Any, str | None]:
    """The split a run that validated on another one is finally scored on: (sequence, None);
    (None, why) when the dataset has no usable test split (Cityscapes: its test labels are all
    void); (None, None) when there is nothing to do (the run validated on ``test``, or the
    reader has no splits)."""
    from evsmap.train.data import open_splits

    if splits.val_split in (None, TEST_SPLIT):
        return None, None
    try:
        test = open_splits(opts.dataset, reader=opts.reader, reader_options=opts.reader_options,
                           train_split=TEST_SPLIT, val_split=TEST_SPLIT, limit=opts.limit).val
    except EvsmapError as exc:
        return None, f"no {TEST_SPLIT} split to score ({exc})"
    if TEST_SPLIT in (test.meta.get("void_label_splits") or ()):
        return None, f"the {TEST_SPLIT} labels of {splits.reader} are all void"
    return test, None


def card_has_test(path: Path) -> bool:
    """Whether the card of weights file ``path`` records a final test pass."""
    from evsmap.segmenters.weights import read_checkpoint

    try:
        saved = read_checkpoint(path)
        return isinstance(saved, dict) and "test_split" in dict(saved.get("card") or {})
    except (EvsmapError, OSError):
        return False


def final_test(opts: RunOptions, splits: Splits, segmenter, out: Path, *, device: torch.device,
               bar: bool = False) -> dict[str, Any] | None:
    """Score ``best.pt``'s weights on the test split (rank 0, after the last epoch, through
    :func:`validate` as validation does, so ``evsmap eval`` gives the same mIoU), write
    ``test_miou``, ``test_split`` and ``test_frames`` into its card (the file rewritten
    atomically, its tensors unchanged) and return them; None when there is no test pass (see
    :func:`open_test_split`; a note says why). The network keeps ``best.pt``'s weights."""
    from evsmap.metrics import ConfusionMatrix
    from evsmap.train.checkpoint import read_weights_file

    def note(text: str) -> None:
        opts.say(f"note: no final test pass: {text}")

    sequence, why = open_test_split(opts, splits)
    if sequence is None:
        if why:
            note(why)
        return None
    t0 = time.perf_counter()
    state, card = read_weights_file(out / BEST)
    segmenter.module.load_state_dict(state, strict=True)
    segmenter.module.eval()
    try:
        counts = validate(segmenter, sequence, Processes(0, 1, 0, device, None, False), bar=bar)
    except EvsmapError as exc:
        note(str(exc))
        return None
    if not counts.sum():
        note(f"every label of the {TEST_SPLIT} split is void")
        return None
    miou = ConfusionMatrix.from_matrix(counts).result().miou
    test_miou = None if math.isnan(miou) else float(miou)
    fields: dict[str, Any] = {"test_miou": test_miou, "test_split": TEST_SPLIT,
                              "test_frames": len(sequence)}
    card.update(fields)
    save_weights(out / BEST, state, card)
    opts.say(f"test mIoU {percent(test_miou)} ({_best_text(card)}, {len(sequence)} frames of "
             f"split {TEST_SPLIT}, {time.perf_counter() - t0:.1f} s)")
    return fields


def _best_text(card: dict[str, Any]) -> str:
    epoch = card.get("val_epoch") or card.get("epochs")
    return f"best.pt, epoch {epoch}" if epoch else "best.pt"
