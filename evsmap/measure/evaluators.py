"""Evaluators: what the measurement engine (:mod:`evsmap.measure.engine`) computes from the
frames it runs, kept apart from the timed loops.

Segmentation evaluators (:class:`SegmentationEvaluator`) see every frame with its observation:
``reset()``, ``process(index, frame, observation)`` per frame, ``evaluate()`` at the end.
Map evaluators (:class:`MapEvaluator`) see the finished map: ``evaluate(updater)``.

Built in:

* :class:`ConfusionEvaluator` - one dataset-level confusion matrix (detectron2's
  ``SemSegEvaluator``; the ignore label is handled once, by
  :class:`~evsmap.metrics.ConfusionMatrix`) and its mIoU;
* :class:`KeepObservations` - the observations, in order, each optionally handed to a function
  (the segmentation cache writes them to disk);
* :class:`MapFiles` - the map's ``.ot`` size in each file format (the paper's "Map Size"),
  optionally the map written to a path;
* :class:`MapStatistics` - the octree's node and leaf counts, OctoMap's memory model, the bytes
  of the arrays that hold the map;
* :class:`MapQualityEvaluator` - precision, recall and semantic accuracy against ground-truth
  voxels (:func:`~evsmap.metrics.evaluate_map`).
"""

from __future__ import annotations

import abc
import functools
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any

from evsmap.data import Frame, SemanticObservation
from evsmap.errors import EvsmapError, InvalidDataError
from evsmap.interfaces import FILE_FORMATS, MapStats, MapUpdater, check_file_format

if TYPE_CHECKING:
    from evsmap.metrics import ConfusionMatrix, SegmentationResult
    from evsmap.metrics.mapping import MapQuality


class SegmentationEvaluator(abc.ABC):
    """Sees every segmented frame; ``name`` keys its result in the engine's ``results``."""

    name: str = "segmentation"

    def reset(self) -> None:  # noqa: B027 (optional hook: an evaluator may keep nothing)
        """Forget earlier frames (called before the first)."""

    def check(self, index: int, frame: Frame) -> None:  # noqa: B027 (optional hook)
        """A frame before it is segmented: raise an :class:`EvsmapError` if this evaluator
        cannot use it (so the user hears the evaluator's reason, not the segmenter's)."""

    @abc.abstractmethod
    def process(self, index: int, frame: Frame, observation: SemanticObservation) -> None:
        """One frame and its observation."""

    @abc.abstractmethod
    def evaluate(self) -> Any:
        """The result over every frame processed."""


class MapEvaluator(abc.ABC):
    """Sees the finished map; ``name`` keys its result in the engine's ``results``."""

    name: str = "map"

    @abc.abstractmethod
    def evaluate(self, updater: MapUpdater) -> Any:
        """The result for the map ``updater`` holds."""


# ------------------------------------------------------------------------------- segmentation
class ConfusionEvaluator(SegmentationEvaluator):
    """A dataset-level confusion matrix of the predicted top-1 class against the labels.

    Args:
        num_classes: the segmenter's classes (the matrix's size).
        class_names: names for the per-class scores (default: none).
        ignore_index: the labels' void value (default: evsmap's, 255).
        source: the dataset's name, for messages.
        needs: what an unlabelled frame's message says is needed.
        name: the key of the result.
    """

    def __init__(self, *, num_classes: int, class_names: Sequence[str] = (),
                 ignore_index: int | None = None, source: str | None = None,
                 needs: str = "scoring a segmenter needs a labelled dataset",
                 name: str = "confusion") -> None:
        from evsmap.metrics import ConfusionMatrix

        self.name = name
        self.source = source
        self.needs = needs
        self.class_names = tuple(class_names)
        self._make: Callable[[], ConfusionMatrix] = (
            functools.partial(ConfusionMatrix, num_classes) if ignore_index is None
            else functools.partial(ConfusionMatrix, num_classes, ignore_index))
        self.matrix = self._make()

    def reset(self) -> None:
        self.matrix = self._make()

    def check(self, index: int, frame: Frame) -> None:
        if frame.labels is None:
            where = f" of {self.source!r}" if self.source else ""
            raise EvsmapError(f"frame {frame.name!r}{where} has no ground-truth labels: "
                              f"{self.needs}")

    def process(self, index: int, frame: Frame, observation: SemanticObservation) -> None:
        self.check(index, frame)
        labels = frame.labels
        assert labels is not None  # check() refused the frame otherwise
        self.matrix.update(observation.argmax, labels)

    def evaluate(self) -> SegmentationResult:
        """The :class:`~evsmap.metrics.SegmentationResult` (mIoU over the classes present in
        ground truth or prediction)."""
        return self.matrix.result(class_names=self.class_names)


class KeepObservations(SegmentationEvaluator):
    """The observations in frame order; each also handed to ``sink(position, observation)``
    when given (e.g. written to a cache as it comes, so memory holds one at a time with
    ``keep=False``).

    Args:
        sink: called with each observation's position and the observation.
        keep: keep the observations in memory (the result); else the result is their count.
        name: the key of the result.
    """

    def __init__(self, *, sink: Callable[[int, SemanticObservation], None] | None = None,
                 keep: bool = True, name: str = "observations") -> None:
        self.name = name
        self.sink = sink
        self.keep = keep
        self.observations: list[SemanticObservation] = []
        self.count = 0

    def reset(self) -> None:
        self.observations, self.count = [], 0

    def process(self, index: int, frame: Frame, observation: SemanticObservation) -> None:
        if self.sink is not None:
            self.sink(self.count, observation)
        if self.keep:
            self.observations.append(observation)
        self.count += 1

    def evaluate(self) -> list[SemanticObservation] | int:
        return self.observations if self.keep else self.count


# ------------------------------------------------------------------------------------ mapping
def write_map(updater: MapUpdater, path: str | PathLike[str], file_format: str = "full") -> int:
    """``updater.write(path, file_format)``, a format it does not write refused first. Returns
    the bytes written."""
    check_file_format(updater, file_format)
    return int(updater.write(path, file_format))


@dataclass(frozen=True)
class MapFileSizes:
    """The map's ``.ot`` bytes in each format, and the file written where one was asked for."""

    sizes: dict[str, int]
    file: str | None = None
    file_format: str = "full"

    @property
    def written_bytes(self) -> int:
        """The bytes of the file in ``file_format`` (written to ``file`` or measured)."""
        return self.sizes[self.file_format]


class MapFiles(MapEvaluator):
    """The map's file sizes: each of ``formats`` written to a temporary folder and measured;
    with ``out``, the map also written there in ``file_format``.

    Args:
        formats: the file formats to measure.
        out: where to write the map (``None``: nowhere).
        file_format: the format of ``out``.
        name: the key of the result.
    """

    def __init__(self, *, formats: Sequence[str] = FILE_FORMATS,
                 out: str | PathLike[str] | None = None, file_format: str = "full",
                 name: str = "files") -> None:
        for fmt in (*formats, file_format):
            if fmt not in FILE_FORMATS:
                raise InvalidDataError(f"file format must be one of {', '.join(FILE_FORMATS)}, "
                                       f"got {fmt!r}")
        self.formats = tuple(formats)
        self.out = None if out is None else Path(out)
        self.file_format = file_format
        self.name = name

    def evaluate(self, updater: MapUpdater) -> MapFileSizes:
        with tempfile.TemporaryDirectory() as tmp:
            sizes = {fmt: write_map(updater, Path(tmp) / f"{fmt}.ot", fmt)
                     for fmt in self.formats if fmt in updater.file_formats()}
        file = None
        if self.out is not None:
            sizes[self.file_format] = write_map(updater, self.out, self.file_format)
            file = str(self.out)
        return MapFileSizes(sizes=sizes, file=file, file_format=self.file_format)


def pruned_share(updater: MapUpdater) -> float | None:
    """The share of the finest leaves merged into pruned nodes
    (:meth:`MapUpdater.pruned_share`), else None."""
    return updater.pruned_share()


class PrunedShare(MapEvaluator):
    """:func:`pruned_share` of the map, read off the tree the other evaluators of the same
    pass build (the engine's :meth:`~evsmap.interfaces.MapUpdater.reuse_tree`) rather than a
    tree of its own afterwards.

    Args:
        name: the key of the result.
    """

    def __init__(self, *, name: str = "pruned_share") -> None:
        self.name = name

    def evaluate(self, updater: MapUpdater) -> float | None:
        return pruned_share(updater)


class MapStatistics(MapEvaluator):
    """:class:`MapStats` of the map.

    Args:
        name: the key of the result.
    """

    def __init__(self, *, name: str = "stats") -> None:
        self.name = name

    def evaluate(self, updater: MapUpdater) -> MapStats:
        stats = updater.stats()
        measured = updater.memory_nbytes()
        return MapStats(nodes=int(stats.nodes), leaves=int(stats.leaves),
                        octomap_memory_bytes=stats.octomap_memory_bytes,
                        map_nbytes=None if measured is None else int(measured))


class MapQualityEvaluator(MapEvaluator):
    """The map's 3D quality against ground-truth voxels (:func:`evsmap.metrics.evaluate_map`);
    ``None`` for an updater without a leaf map to compare.

    Args:
        truth: the ground truth at the map's resolution (e.g.
            ``SyntheticSequence.ground_truth(resolution)``).
        name: the key of the result.
    """

    def __init__(self, truth: Any, *, name: str = "quality") -> None:
        self.truth = truth
        self.name = name

    def evaluate(self, updater: MapUpdater) -> MapQuality | None:
        if not updater.has_leaf_map:
            return None
        from evsmap.metrics import evaluate_map

        return evaluate_map(updater, self.truth)
