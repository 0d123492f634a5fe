"""The synthetic room rendered once into evsmap's cache and read back like a recorded dataset.

Rendering a 640x480 frame (Embree ray casting, texture, shading, noise) costs about 70 ms of one
core, several times what decoding a recorded frame costs (TUM: about 12 ms). Where the synthetic
room stands in for a recorded sequence - Table IV's mapping runs, ``evsmap map synthetic``'s
rates - its frames are rendered once into ``<cache>/sequences/`` in the TUM RGB-D
layout (with labels and ``evsmap.json``) and read back: PNG images and the text files are
lossless and the poses are written at full precision, so every frame is bit for bit the one
rendered (``tests/synth/test_cached.py``). The folder is keyed by the options and a digest of
``evsmap.synth``'s source, so a renderer change never reuses an old rendering.
"""

from __future__ import annotations

from pathlib import Path

from evsmap.data import Frame, Sequence, VoxelLabels
from evsmap.errors import DataFormatError, EvsmapError
from evsmap.synth.sequence import SyntheticSequence


def cache_folder(options: dict) -> Path:
    """Where the rendering of the synthetic sequence with ``options`` lives."""
    from evsmap.cache import cache_dir, source_digest

    o = {"scene": "living_room", "seed": 0, "frames": 60, "width": 640, "height": 480,
         "noise": False, **options}
    return cache_dir("sequences") / (
        f"synthetic-{o['scene']}-s{o['seed']}-{o['width']}x{o['height']}-{o['frames']}f"
        + ("-noise" if o.get("noise") else "") + f"-{source_digest('evsmap.synth')}")


def rendered_folder(options: dict) -> Path:
    """:func:`cache_folder` for ``options``, rendered there first when it is not yet (a
    progress bar on a terminal)."""
    from evsmap.readers.tum import METADATA_FILE
    from evsmap.synth.write import write_synthetic

    folder = cache_folder(options)
    if not (folder / METADATA_FILE).is_file():
        write_synthetic(SyntheticSequence(**options), folder, overwrite=True)
    return folder


class CachedSynthetic(Sequence):
    """A synthetic sequence whose frames are read from its cached rendering (TUM reader),
    with the live sequence's name, classes and ground-truth voxels.

    Args:
        options: :class:`SyntheticSequence`'s options (scene, seed, frames, width, height,
            noise).
    """

    folder: Path

    def __init__(self, **options) -> None:
        from evsmap.registry import READERS

        self.live = SyntheticSequence(**options)  # checks the options before rendering
        self.folder = rendered_folder(options)
        try:
            self._tum = READERS.create("tum", path=str(self.folder))
        except EvsmapError as exc:
            raise self._damaged(exc) from None
        meta = dict(self.live.meta, render="cached", path=str(self.folder))
        super().__init__(self.live.name, self._tum.intrinsics, meta)
        self.class_names = self.live.class_names
        self.num_classes = self.live.num_classes

    def __len__(self) -> int:
        return len(self._tum)

    def frame(self, index: int) -> Frame:
        try:
            return self._tum.frame(index)
        except EvsmapError as exc:
            raise self._damaged(exc) from None

    def _damaged(self, exc: EvsmapError) -> DataFormatError:
        """The reader's one-line error with what to do about a damaged cache folder."""
        return DataFormatError(f"{exc} (in evsmap's cached rendering of the synthetic sequence; "
                               f"delete {self.folder} to render it again)")

    def frames_identity(self) -> str:
        """The rendering's folder and its metadata file's time and size: what the frames are
        (the folder names the options and the renderer's source digest). Not the folder's own
        time, which the ground truth's cache written beside the frames changes (that made the
        segmentation cache miss once per cold run: 18 s of the oracle and 300 MB again)."""
        from evsmap.readers.tum import METADATA_FILE

        st = (self.folder / METADATA_FILE).stat()
        return f"{self.folder.resolve()}:{st.st_mtime_ns}:{st.st_size}"

    @property
    def has_ground_truth(self) -> bool:
        return True

    def ground_truth(self, resolution: float) -> VoxelLabels:
        """Occupied voxels of the room with their labels (the live sequence's)."""
        return self.live.ground_truth(resolution)


def cached_ground_truth(options: dict, resolution: float) -> VoxelLabels:
    """The room's ground-truth voxels at ``resolution`` (:meth:`SyntheticSequence.
    ground_truth`), computed once beside its cached rendering (``groundtruth-<m>.npz``,
    lossless: the same keys and labels bit for bit) and read back after: every mapping run of
    a reproduce run scores against the same room (1.6 s to compute at 2 cm here, once per run
    before this cache)."""
    import numpy as np

    from evsmap.fileio import atomic_write

    folder = cache_folder(options)
    path = folder / f"groundtruth-{resolution!r}.npz"
    if path.is_file():
        try:
            with np.load(path) as data:
                return VoxelLabels(data["keys"], data["labels"], float(resolution))
        except (OSError, ValueError, KeyError):
            pass  # damaged: computed again and rewritten below
    truth = SyntheticSequence(**options).ground_truth(resolution)
    folder.mkdir(parents=True, exist_ok=True)
    with atomic_write(path, "wb") as f:
        np.savez(f, keys=truth.keys, labels=truth.labels)
    return truth
