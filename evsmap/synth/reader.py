"""The ``synthetic`` reader: the built-in procedural rooms rendered on demand."""

from __future__ import annotations

from typing import Any

from evsmap.errors import EvsmapError
from evsmap.registry import READERS, Takes
from evsmap.synth.scene import DEFAULT_SCENE

RENDERS = ("live", "cached")


@READERS.register("synthetic", takes=Takes())  # built from options: no path
def open_synthetic(*, scene: str = DEFAULT_SCENE, seed: int = 0, frames: int = 60,
                   width: int = 640, height: int = 480, noise: bool = False, laps: int = 1,
                   render: str = "live"):
    """Built-in procedural indoor room (NYUv2-40 labels) rendered with Open3D ray casting;
    ``render=cached`` renders it once into the cache and reads the frames back like a recorded
    sequence (bit-identical; what ``evsmap map`` and Table IV time). ``laps``: times the camera
    goes round the room (the long run with revisits: ``-r laps=4 -r frames=640``)."""
    options: dict[str, Any] = dict(scene=scene, seed=seed, frames=frames, width=width,
                                   height=height, noise=noise)
    if laps != 1:  # one lap: the options (and the cache key) of earlier versions
        options["laps"] = laps
    if render not in RENDERS:
        raise EvsmapError(f"synthetic option render must be one of {', '.join(RENDERS)}, got "
                          f"{render!r}")
    if render == "cached":
        from evsmap.synth.cached import CachedSynthetic

        return CachedSynthetic(**options)
    from evsmap.synth.sequence import SyntheticSequence  # numba: only when one is opened

    return SyntheticSequence(**options)
