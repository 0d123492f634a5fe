"""The two plug-in interfaces: segmenters (2D) and map updaters (3D).

Later modules implement them; the runner, the gate and the CLI only talk to what is declared
here (no ``hasattr`` probing). A reader is any factory registered in
:data:`evsmap.registry.READERS` that returns a :class:`evsmap.data.Sequence`.
"""

from __future__ import annotations

import abc
import contextlib
from collections.abc import Mapping
from dataclasses import dataclass
from os import PathLike
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from evsmap.data import Frame, SemanticObservation
from evsmap.errors import InvalidDataError

if TYPE_CHECKING:  # torch is heavy to import; only type checkers need it here
    import torch


class Segmenter(abc.ABC):
    """Turns a :class:`Frame` into a :class:`SemanticObservation`.

    Attributes:
        num_classes: size of the label set the segmenter predicts.
        class_names: one name per class id.
        uses_depth: whether the depth image is an input (RGB-D networks) or ignored.
        weights: the weight file loaded, or None (random weights, or not a network).
        backend: what runs the network (``"torch"``, ``"onnxruntime"``); ``"torch"`` for a
            segmenter that is not a network.
        default_size: (H, W) a network is measured at when the caller names no size; None for
            a segmenter that is not a network.
        input_size: (H, W) a network resizes frames to before its forward pass
            (:meth:`set_input_size`); None for a segmenter that takes frames as they come.
        last_timings: milliseconds of the last :meth:`predict`'s stages (e.g. ``preprocess``,
            ``network``, ``postprocess``); empty where a segmenter does not split them.
        network_threads: the intra-op threads a network's next forward pass runs with (its
            logits depend on them); None for a segmenter that is not a network.
    """

    num_classes: int
    class_names: tuple[str, ...]
    uses_depth: ClassVar[bool] = True
    weights: str | None = None
    backend: str = "torch"
    default_size: tuple[int, int] | None = None
    input_size: tuple[int, int] | None = None
    last_timings: Mapping[str, float] = MappingProxyType({})

    @property
    @abc.abstractmethod
    def module(self) -> torch.nn.Module | None:
        """The torch module that does the work (for parameter/FLOP counts and export), or
        ``None`` for segmenters that are not networks."""

    @abc.abstractmethod
    def predict(self, frame: Frame, *, k: int = 3) -> SemanticObservation:
        """Top-``k`` classes and probabilities for every pixel of ``frame``."""

    def predict_at(self, frame: Frame, pixels: np.ndarray | None, *, k: int = 3
                   ) -> SemanticObservation:
        """:meth:`predict` for a caller that reads the observation only at ``pixels`` (a bool
        HxW mask; None: every pixel): exact there, and valid but unspecified elsewhere (a
        network segmenter leaves class 0 with probability 0 there). The default predicts every
        pixel; a segmenter whose work scales with the pixels overrides it."""
        # k left out at its default: a plug-in's (or a wrapper's) predict(frame) keeps working
        return self.predict(frame) if k == 3 else self.predict(frame, k=k)

    @property
    def input_names(self) -> tuple[str, ...]:
        """Names of the network's inputs, in order (the ONNX graph's); () for a segmenter that is
        not a network."""
        return ()

    def example_inputs(self, height: int, width: int) -> tuple[torch.Tensor, ...]:
        """Deterministic inputs of the network's shapes (batch 1) at ``height`` x ``width``, for
        parameter/FLOP counts, speed and export.

        Raises:
            InvalidDataError: the segmenter is not a network (:attr:`module` is None).
        """
        raise InvalidDataError(f"{type(self).__name__} is not a network: it has no inputs to "
                               f"measure")

    def set_input_size(self, size: tuple[int, int]) -> None:
        """Resize frames to ``size`` (H, W) before the network from the next :meth:`predict`
        on (``evsmap predict`` follows each frame's size this way).

        Raises:
            InvalidDataError: the segmenter has no input size (:attr:`input_size` is None).
        """
        raise InvalidDataError(f"{type(self).__name__} takes frames as they come: it has no "
                               f"input size to set")

    def set_threads(self, threads: int | None = None, *, spinning: bool = True
                    ) -> dict[str, Any]:
        """Threads of the segmenter's own runtime (a network's forward pass: ONNX Runtime's
        intra-op pool, or torch's threads around the forward alone; ``None``: the runtime's
        default) and whether ONNX Runtime's idle workers may busy-wait (``spinning``: good
        alone, bad when other stages of a pipeline need the cores). A network's logits depend
        on this count (docs/cli.md, "Thread independence"). Returns what it uses now (``{}``
        for a segmenter without such a runtime)."""
        return {}

    @property
    def network_threads(self) -> int | None:
        """The intra-op threads the next forward pass runs with; None (the default) for a
        segmenter that is not a network."""
        return None

    def __call__(self, frame: Frame) -> SemanticObservation:
        return self.predict(frame)


@dataclass(frozen=True)
class MapStats:
    """Size of a map: what :meth:`MapUpdater.stats` returns, and (with ``map_nbytes``) what
    :class:`evsmap.measure.evaluators.MapStatistics` records.

    Attributes:
        nodes, leaves: octree nodes and leaves (a plug-in without an octree: its cells).
        octomap_memory_bytes: OctoMap's ``memoryUsage()`` for a tree of these nodes in the
            compared system's C++ node type - a formula over the counts, not a measurement
            (measured memory: :mod:`evsmap.measure.memory`); ``None`` where it does not apply.
        map_nbytes: measured - the bytes of the arrays evsmap holds the map in
            (:meth:`MapUpdater.memory_nbytes`); ``None`` where not measured or for a map held
            by a C++ library.
    """

    nodes: int
    leaves: int
    octomap_memory_bytes: int | None = None
    map_nbytes: int | None = None


UNKNOWN, FREE, OCCUPIED = -1, 0, 1


@dataclass(frozen=True)
class PointQuery:
    """What a map knows at N query points.

    Attributes:
        state: ``int8`` (N,), -1 unknown, 0 free, 1 occupied.
        probability: ``float32`` (N,) occupancy probability, NaN where unknown.
        label: ``int16`` (N,) most likely class, -1 where unknown, free or unlabelled.
    """

    state: np.ndarray
    probability: np.ndarray
    label: np.ndarray


FILE_FORMATS = ("full", "published", "colour", "message")
"""A map's file formats: ``full`` - the resumable state; ``published`` - the file the compared
system itself saves; ``colour`` - a ``ColorOcTree`` (log-odds and one colour a node, the top
class's colour for semantic maps) that any OctoMap tool opens; ``message`` - the full map as the
system's ROS node sends it (``octomap_full``), offered where that is not the saved file (SSMI's
carries the semantics; its ``.ot`` takes a tree id of its own, see
:meth:`~evsmap.updaters.base.OctreeUpdater.write`)."""


def check_file_format(updater: MapUpdater, file_format: str) -> None:
    """Refuse a ``file_format`` that is not one of :data:`FILE_FORMATS`, or one ``updater``
    does not write.

    Raises:
        InvalidDataError: names the formats there are, or those the updater writes.
    """
    if file_format not in FILE_FORMATS:
        raise InvalidDataError(f"file format must be one of {', '.join(FILE_FORMATS)}, got "
                               f"{file_format!r}")
    if file_format not in updater.file_formats():
        raise InvalidDataError(f"{type(updater).__name__} writes no {file_format} file (it "
                               f"writes {', '.join(updater.file_formats())})")


class MapUpdater(abc.ABC):
    """Integrates frames (and optionally their semantics) into a volumetric map.

    Attributes:
        resolution: leaf voxel edge length in metres.
        uses_semantics: whether :meth:`integrate` reads the observation.
    """

    resolution: float

    @property
    def uses_semantics(self) -> bool:
        """Whether :meth:`integrate` reads the observation (False by default; a subclass sets
        it as a class attribute, or as a property where its instances differ)."""
        return False

    has_leaf_map: ClassVar[bool] = False
    """Whether :meth:`occupied_labels` can list the map's occupied leaves (evsmap's octree
    updaters); the map-quality metrics need it."""

    @abc.abstractmethod
    def integrate(self, frame: Frame, observation: SemanticObservation | None = None) -> None:
        """Fuse one frame (depth, colour, pose, intrinsics) and its semantics into the map."""

    def semantic_pixels(self, frame: Frame) -> np.ndarray | None:
        """The pixels of ``frame`` whose observation :meth:`integrate` may read, as a bool HxW
        mask (a superset is fine), or None for every pixel (the default; a point-cloud frame).
        A mapping loop passes it to :meth:`Segmenter.predict_at`."""
        return None

    @abc.abstractmethod
    def stats(self) -> MapStats:
        """Current node and memory counts."""

    @abc.abstractmethod
    def write(self, path: str | PathLike[str], file_format: str = "full") -> int:
        """Write the map to ``path`` in ``file_format`` (one of :meth:`file_formats`); returns
        the file size in bytes (the paper's "Map Size").

        ``"full"`` is the resumable state, ``"published"`` the file the compared system itself
        saves (the same file where the updater keeps one form), ``"colour"`` a
        ``ColorOcTree``, ``"message"`` the map as the system's ROS node sends it where that
        differs (see :meth:`~evsmap.updaters.base.OctreeUpdater.write`).

        Raises:
            InvalidDataError: a format the updater does not write (:func:`check_file_format`).
        """

    @abc.abstractmethod
    def query(self, points: np.ndarray) -> PointQuery:
        """Occupancy and label at ``points`` (N x 3 world coordinates, metres)."""

    front_end: ClassVar[str | None] = None
    """How a frame becomes hits and misses (:data:`evsmap.mapping.generator.FRONT_ENDS`), or
    None for an updater that does not say (a C++ library's ``insertPointCloud``)."""

    def front_end_counts(self) -> dict[str, list[int]]:
        """Per integrated frame, what the front end produced: ``centroids`` (the filtered cloud's
        points, or the voxels holding the points), ``hits`` (occupied updates) and ``rays`` (the
        points ray cast); empty where the updater does not count."""
        return {}

    def file_formats(self) -> tuple[str, ...]:
        """The :data:`FILE_FORMATS` this updater writes; by default ``full`` and
        ``published``, one file that is both."""
        return ("full", "published")

    def pruned_share(self) -> float | None:
        """The share of the map's finest leaves merged into pruned nodes; None where the
        updater does not say (a map without an octree of evsmap's)."""
        return None

    def reuse_tree(self) -> contextlib.AbstractContextManager[None]:
        """A block in which the map does not change, so that what is derived from it (an
        octree updater's pruned tree) is built once for every statistic and file asked for
        inside; a no-op by default."""
        return contextlib.nullcontext()

    def size_readings(self) -> dict[str, int | None]:
        """The map's ``nodes``, ``leaves`` and its size under each reading:
        ``published_bytes`` (the saved file), ``message_bytes`` (the ``octomap_full`` message:
        the saved file where the system sends no other), ``colour_bytes`` (None without a
        colour form) and ``memory_bytes`` (OctoMap's model, None where the updater has none);
        files written to a temporary folder (an octree updater computes them from one build of
        its tree)."""
        import tempfile
        from pathlib import Path

        stats = self.stats()
        with tempfile.TemporaryDirectory() as tmp:
            published = int(self.write(Path(tmp) / "published.ot", "published"))
            message = (int(self.write(Path(tmp) / "message.ot", "message"))
                       if "message" in self.file_formats() else published)
            colour = (int(self.write(Path(tmp) / "colour.ot", "colour"))
                      if "colour" in self.file_formats() else None)
        return {"nodes": int(stats.nodes), "leaves": int(stats.leaves),
                "published_bytes": published, "message_bytes": message, "colour_bytes": colour,
                "memory_bytes": stats.octomap_memory_bytes}

    def memory_nbytes(self) -> int | None:
        """Bytes of the arrays that hold the map (measured from their ``nbytes``), or None where
        the updater cannot say (a map held in C++)."""
        return None

    def occupied_voxels(self) -> int | None:
        """How many occupied leaves the map holds (0: a map of free space only); None where
        the updater cannot say. An octree that prunes counts a merged leaf once."""
        return len(self.occupied_labels()[0]) if self.has_leaf_map else None

    def occupied_labels(self) -> tuple[np.ndarray, np.ndarray]:
        """The occupied finest-level leaves and their most likely class: (sorted ``int64``
        voxel codes, ``int16`` labels, -1 where a leaf has no class).

        Raises:
            InvalidDataError: the updater has no leaf map (:attr:`has_leaf_map` is False).
        """
        raise InvalidDataError(f"{type(self).__name__} exposes no leaf map (the map-quality "
                               f"metrics need an octree updater of evsmap's)")
