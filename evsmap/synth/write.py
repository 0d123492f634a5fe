"""A synthetic sequence written to disk in the TUM RGB-D layout, with its ``evsmap.json``
(``evsmap synth``, and the runner's cached synthetic sequence)."""

from __future__ import annotations

import json
from pathlib import Path

from evsmap.classes import NYU40_CLASSES
from evsmap.fileio import staging_folder
from evsmap.progress import progress
from evsmap.readers.images import DEPTH_SCALE
from evsmap.readers.tum import METADATA_FILE, write_tum
from evsmap.synth.sequence import GENERATOR_VERSION, SyntheticSequence
from evsmap.version import evsmap_version


def metadata(seq: SyntheticSequence) -> dict:
    """The folder's ``evsmap.json``: format, generator and evsmap versions and the options the
    sequence was rendered with."""
    return {
        "format": "evsmap-synthetic", "format_version": 1,
        "generator_version": GENERATOR_VERSION, "evsmap_version": evsmap_version(),
        "scene": seq.scene, "seed": seq.seed, "frames": len(seq), "noise": seq.noise,
        "width": seq.intrinsics.width, "height": seq.intrinsics.height,
        "intrinsics": seq.intrinsics.as_dict(), "depth_scale": DEPTH_SCALE,
        "room_size_m": list(seq.room.size), "classes": list(NYU40_CLASSES), "void_label": 255,
    }


def write_synthetic(seq: SyntheticSequence, out: Path, *, overwrite: bool = False) -> None:
    """Render ``seq`` into ``out`` atomically: a partial folder is renamed into place only when
    complete, so an existing ``out`` is never left half-replaced."""
    with staging_folder(Path(out), overwrite=overwrite, what="--out ") as partial:
        write_tum(seq, partial, quaternions=seq.quaternions,
                  progress=lambda frames: progress(frames, total=len(seq), desc="rendering"))
        (partial / METADATA_FILE).write_text(json.dumps(metadata(seq), indent=2) + "\n")


__all__ = ["metadata", "write_synthetic"]
