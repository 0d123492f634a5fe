"""ScanNet scenes as mapping sequences: where the runner finds the release, which scenes it
maps, and how one is opened.

The release sits under the data root as ``scannet/`` in its official layout (``scans/``,
``scannetv2-labels.combined.tsv``, the split files). A scene is the sequence
``scannet-<scene id>``; the scenes mapped are ``--scannet-scenes``, else the first
:data:`AUTO_SCENES` of the validation split found there (the scenes present, by name, without
the split file), read every ``--scannet-step``-th frame (ScanNet records at 30 Hz) of those whose
pose is valid (ScanNet marks a frame its tracking lost with -inf).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from evsmap.errors import EvsmapError

if TYPE_CHECKING:  # the report imports this module's names: it stays light (no torch)
    from evsmap.data import Sequence
    from evsmap.runner.context import RunContext

SCANNET = "scannet"
"""The data root folder of the release, and the sequence of the n/a record without it."""
SCANNET_SEQUENCE_PREFIX = "scannet-"
AUTO_SCENES = 2


def scannet_sequence(scene: str) -> str:
    return SCANNET_SEQUENCE_PREFIX + scene


def is_scannet_sequence(name: str) -> bool:
    return name == SCANNET or name.startswith(SCANNET_SEQUENCE_PREFIX)


def scannet_scenes(ctx: RunContext) -> list[str]:
    """The ScanNet scenes this run maps (module notes); empty without the dataset."""
    root = ctx.dataset_path(SCANNET)
    if root is None:
        return []
    if ctx.scannet_scenes:
        return list(ctx.scannet_scenes)
    from evsmap.errors import DataFormatError
    from evsmap.readers.scannet.labelmap import SCENE_ID, SPLIT_FILE, read_split

    scans = Path(root) / "scans"
    present = sorted(p.name for p in scans.iterdir() if SCENE_ID.match(p.name) and p.is_dir()) \
        if scans.is_dir() else []
    order = present
    split = Path(root) / SPLIT_FILE.format("val")
    if split.is_file():
        try:
            val = read_split(split)
        except DataFormatError:
            val = []
        order = [s for s in val if s in present] or present
    return order[:AUTO_SCENES]


def open_scannet(ctx: RunContext, name: str) -> Sequence:
    """The scene of sequence ``name`` (``scannet-<scene id>``)."""
    from evsmap.registry import READERS

    root = ctx.dataset_path(SCANNET)
    if root is None:
        raise EvsmapError(f"sequence {name!r}: no {SCANNET}/ folder under {ctx.roots()}")
    sequence: Sequence = READERS.create(
        "scannet", path=str(root), scene=name.removeprefix(SCANNET_SEQUENCE_PREFIX),
        step=ctx.scannet_step, drop_lost=True)
    return sequence


__all__ = ["AUTO_SCENES", "SCANNET", "SCANNET_SEQUENCE_PREFIX", "is_scannet_sequence",
           "open_scannet", "scannet_scenes", "scannet_sequence"]
