"""The ``synthetic`` reader: the built-in procedural rooms rendered on demand."""

from __future__ import annotations

from evsmap.registry import READERS
from evsmap.synth.scene import DEFAULT_SCENE
from evsmap.synth.sequence import SyntheticSequence


@READERS.register("synthetic")
def open_synthetic(*, scene: str = DEFAULT_SCENE, seed: int = 0, frames: int = 60,
                   width: int = 640, height: int = 480, noise: bool = False) -> SyntheticSequence:
    """Built-in procedural indoor room (NYUv2-40 labels) rendered with Open3D ray casting."""
    return SyntheticSequence(scene=scene, seed=seed, frames=frames, width=width, height=height,
                             noise=noise)
