"""Dataset-level semantic segmentation scores from one confusion matrix.

The scores follow detectron2's ``SemSegEvaluator``: every labelled pixel of every image adds one
count to ``matrix[ground truth, prediction]``; void ground-truth pixels (``ignore_index``) are
dropped there and nowhere else. From the summed matrix:

* IoU of class c = ``TP / (TP + FP + FN)``, NaN when c occurs neither in the ground truth nor in
  the predictions (``present`` is False); mIoU is the mean over the present classes, so a class
  predicted but never in the ground truth counts with IoU 0.
* pixel accuracy = ``sum(TP) / labelled pixels``; mean accuracy = mean over the classes in the
  ground truth of ``TP / ground-truth pixels``.
* frequency-weighted IoU = ``sum_c IoU_c * (ground-truth pixels of c) / labelled pixels`` over the
  classes in the ground truth.

Scores are fractions in [0, 1] (the paper prints mIoU in percent). Everything is NaN when no
labelled pixel has been seen.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evsmap.data import VOID
from evsmap.errors import InvalidDataError


@dataclass(frozen=True)
class SegmentationResult:
    """Scores of one confusion matrix (fractions; NaN where undefined).

    Attributes:
        miou: mean IoU over the present classes.
        pixel_accuracy: correctly labelled pixels / labelled pixels.
        mean_accuracy: mean per-class recall over the classes in the ground truth.
        frequency_weighted_iou: IoU weighted by ground-truth class frequency.
        per_class_iou: ``float64`` (C,), NaN for absent classes.
        per_class_accuracy: ``float64`` (C,), NaN for classes not in the ground truth.
        present: ``bool`` (C,), the class occurs in the ground truth or the predictions.
        pixels: labelled (non-void) pixels counted.
        class_names: one name per class, or empty.
    """

    miou: float
    pixel_accuracy: float
    mean_accuracy: float
    frequency_weighted_iou: float
    per_class_iou: np.ndarray = field(repr=False)
    per_class_accuracy: np.ndarray = field(repr=False)
    present: np.ndarray = field(repr=False)
    pixels: int
    class_names: tuple[str, ...] = field(default=(), repr=False)

    @property
    def num_classes(self) -> int:
        return int(self.per_class_iou.shape[0])

    def as_dict(self) -> dict:
        """JSON-ready record; NaN becomes ``None``; per-class values are keyed by class name
        (or id) and list the present classes only."""
        names = self.class_names or tuple(str(i) for i in range(self.num_classes))
        return {
            "miou": _num(self.miou),
            "pixel_accuracy": _num(self.pixel_accuracy),
            "mean_accuracy": _num(self.mean_accuracy),
            "frequency_weighted_iou": _num(self.frequency_weighted_iou),
            "pixels": int(self.pixels),
            "num_classes": self.num_classes,
            "present_classes": int(np.count_nonzero(self.present)),
            "per_class_iou": {names[i]: _num(self.per_class_iou[i])
                              for i in np.flatnonzero(self.present)},
        }


def _num(x: float) -> float | None:
    x = float(x)
    return None if np.isnan(x) else x


class ConfusionMatrix:
    """Accumulates ``matrix[gt, pred]`` over images (rows: ground truth, columns: prediction).

    Args:
        num_classes: label set size; valid ids are ``0 .. num_classes - 1``.
        ignore_index: ground-truth value of void pixels (not counted).
    """

    def __init__(self, num_classes: int, ignore_index: int = VOID) -> None:
        if isinstance(num_classes, bool) or not isinstance(num_classes, (int, np.integer)) \
                or num_classes < 1:
            raise InvalidDataError(f"num_classes must be a positive integer, got {num_classes!r}")
        if 0 <= ignore_index < num_classes:
            raise InvalidDataError(
                f"ignore_index {ignore_index} is a valid class id (num_classes {num_classes})")
        self.num_classes = int(num_classes)
        self.ignore_index = int(ignore_index)
        self._matrix = np.zeros((self.num_classes, self.num_classes), dtype=np.int64)

    @classmethod
    def from_matrix(cls, matrix: np.ndarray, ignore_index: int = VOID) -> ConfusionMatrix:
        """A confusion matrix holding given counts (square, non-negative integers)."""
        m = np.asarray(matrix)
        if m.ndim != 2 or m.shape[0] != m.shape[1] or not np.issubdtype(m.dtype, np.integer) \
                or (m.size and m.min() < 0):
            raise InvalidDataError("a confusion matrix must be a square array of counts >= 0")
        out = cls(m.shape[0], ignore_index)
        out._matrix[...] = m
        return out

    @property
    def matrix(self) -> np.ndarray:
        """``int64`` (C, C) counts, rows = ground truth, columns = prediction (a copy)."""
        return self._matrix.copy()

    @property
    def pixels(self) -> int:
        return int(self._matrix.sum())

    def reset(self) -> None:
        self._matrix[...] = 0

    def update(self, pred: np.ndarray, gt: np.ndarray) -> ConfusionMatrix:
        """Count one image (or any same-shaped integer arrays); returns ``self``.

        Raises:
            InvalidDataError: shapes differ, non-integer arrays, a ground-truth id that is
                neither a class nor void, or a prediction outside ``0 .. num_classes - 1`` at a
                labelled pixel.
        """
        pred = np.asarray(pred)
        gt = np.asarray(gt)
        if pred.shape != gt.shape:
            raise InvalidDataError(f"prediction shape {pred.shape} does not match ground truth "
                                   f"shape {gt.shape}")
        for what, a in (("prediction", pred), ("ground truth", gt)):
            if not (np.issubdtype(a.dtype, np.integer) or a.dtype == bool):
                raise InvalidDataError(f"{what} must be an integer label array, got {a.dtype}")
        gt = gt.ravel().astype(np.int64)
        pred = pred.ravel().astype(np.int64)
        keep = gt != self.ignore_index
        gt, pred = gt[keep], pred[keep]
        n = self.num_classes
        if gt.size:
            bad = (gt < 0) | (gt >= n)
            if np.any(bad):
                raise InvalidDataError(
                    f"ground truth has label {int(gt[bad][0])}: neither a class id in "
                    f"[0, {n - 1}] nor void ({self.ignore_index})")
            bad = (pred < 0) | (pred >= n)
            if np.any(bad):
                raise InvalidDataError(
                    f"prediction has class {int(pred[bad][0])} at a labelled pixel, outside "
                    f"[0, {n - 1}] ({n} classes): does the segmenter use the dataset's label "
                    f"set?")
            self._matrix += np.bincount(gt * n + pred, minlength=n * n).reshape(n, n)
        return self

    def merge(self, other: ConfusionMatrix) -> ConfusionMatrix:
        """Add another matrix's counts (same classes and void id); returns ``self``."""
        if not isinstance(other, ConfusionMatrix):
            raise TypeError(f"can only merge a ConfusionMatrix, got {type(other).__name__}")
        if other.num_classes != self.num_classes or other.ignore_index != self.ignore_index:
            raise InvalidDataError(
                f"cannot merge a {other.num_classes}-class matrix (void {other.ignore_index}) "
                f"into a {self.num_classes}-class one (void {self.ignore_index})")
        self._matrix += other._matrix
        return self

    def result(self, class_names: tuple[str, ...] | list[str] = ()) -> SegmentationResult:
        """The scores of the counts so far (see the module notes)."""
        m = self._matrix.astype(np.float64)
        tp = np.diag(m)
        gt_pixels = m.sum(axis=1)
        pred_pixels = m.sum(axis=0)
        union = gt_pixels + pred_pixels - tp
        present = union > 0
        in_gt = gt_pixels > 0
        total = gt_pixels.sum()
        with np.errstate(divide="ignore", invalid="ignore"):
            iou = np.where(present, tp / np.where(present, union, 1.0), np.nan)
            acc = np.where(in_gt, tp / np.where(in_gt, gt_pixels, 1.0), np.nan)
        nan = float("nan")
        miou = float(iou[present].mean()) if present.any() else nan
        mean_acc = float(acc[in_gt].mean()) if in_gt.any() else nan
        pixel_acc = float(tp.sum() / total) if total > 0 else nan
        fw = float((iou[in_gt] * gt_pixels[in_gt]).sum() / total) if total > 0 else nan
        names = tuple(class_names)
        if names and len(names) != self.num_classes:
            raise InvalidDataError(f"{len(names)} class names for {self.num_classes} classes")
        return SegmentationResult(miou=miou, pixel_accuracy=pixel_acc, mean_accuracy=mean_acc,
                                  frequency_weighted_iou=fw, per_class_iou=iou,
                                  per_class_accuracy=acc, present=present,
                                  pixels=int(self._matrix.sum()), class_names=names)
