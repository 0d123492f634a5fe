"""The built-in synthetic RGB-D sequence: a procedural room, a camera path and the renderer."""

from __future__ import annotations

import numpy as np

from evsmap.classes import NYU40_CLASSES
from evsmap.data import Frame, Intrinsics, Sequence
from evsmap.errors import EvsmapError
from evsmap.geometry import pose_matrix
from evsmap.synth.groundtruth import VoxelLabels, ground_truth_voxels
from evsmap.synth.render import RoomRenderer, dequantize_depth, kinect_noise, quantize_depth
from evsmap.synth.scene import DEFAULT_SCENE, build_room
from evsmap.synth.trajectory import room_trajectory

GENERATOR_VERSION = 1
"""Bumped whenever a change alters rendered output for the same options."""


def default_intrinsics(width: int = 640, height: int = 480) -> Intrinsics:
    """A Kinect-v1-like camera (f = 525 px at 640x480, about 63 x 49 deg) scaled to the size."""
    return Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480).scaled(width, height)


class SyntheticSequence(Sequence):
    """Frames rendered on demand from a seeded procedural room.

    Args:
        scene: room type (``bedroom``, ``living_room``, ``office``, ``kitchen``).
        seed: random seed of the room layout, the camera path and the noise.
        frames: number of frames spread over one lap of the room (timestamps follow a 0.5 m/s
            walk).
        width: image width in pixels.
        height: image height in pixels.
        noise: add Kinect-like depth noise and holes (labels and poses stay exact).
        laps: times the camera goes round the room over the ``frames`` (revisits; see
            :func:`~evsmap.synth.trajectory.room_trajectory`).
    """

    intrinsics: Intrinsics  # always set (default_intrinsics of the size)

    def __init__(self, *, scene: str = DEFAULT_SCENE, seed: int = 0, frames: int = 60,
                 width: int = 640, height: int = 480, noise: bool = False, laps: int = 1) -> None:
        for name, value, lo in (("frames", frames, 1), ("width", width, 8), ("height", height, 8),
                                ("laps", laps, 1)):
            if isinstance(value, bool) or not isinstance(value, int) or value < lo:
                raise EvsmapError(
                    f"synthetic option {name} must be an integer >= {lo}, got {value!r}")
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise EvsmapError(
                f"synthetic option seed must be a non-negative integer, got {seed!r}")
        self.room = build_room(scene, seed=seed)
        super().__init__(
            f"synthetic-{scene}-s{seed}" + (f"-{laps}laps" if laps > 1 else ""),
            default_intrinsics(width, height),
            {"layout": "synthetic", "scene": scene, "seed": seed, "noise": noise,
             "room_size": list(self.room.size), "generator_version": GENERATOR_VERSION,
             "ground_truth_source": "the room's visible surfaces, voxelised at the map's "
                                    "resolution"},
        )
        self.scene, self.seed, self.noise = scene, seed, noise
        self.num_classes = len(NYU40_CLASSES)
        self.class_names = NYU40_CLASSES
        self.laps = laps
        self.timestamps, self.translations, self.quaternions = room_trajectory(
            self.room.size, frames, seed=seed, laps=laps)
        self._renderer: RoomRenderer | None = None

    @property
    def renderer(self) -> RoomRenderer:
        if self._renderer is None:
            self._renderer = RoomRenderer(self.room)
        return self._renderer

    def __len__(self) -> int:
        return len(self.timestamps)

    def pose(self, index: int) -> np.ndarray:
        return pose_matrix(self.translations[index], self.quaternions[index])

    def frame(self, index: int) -> Frame:
        rng = np.random.default_rng([self.seed, index, 0x5E7])
        pose = self.pose(index)
        view = self.renderer.render(self.intrinsics, pose, rng=rng)
        depth = view.depth
        if self.noise:
            depth = kinect_noise(depth, view.normals, view.dirs, view.labels, rng=rng)
        depth = dequantize_depth(quantize_depth(depth))
        return Frame(rgb=view.rgb, depth=depth, intrinsics=self.intrinsics, pose=pose,
                     timestamp=float(self.timestamps[index]), labels=view.labels,
                     name=f"{self.timestamps[index]:.6f}")

    @property
    def has_ground_truth(self) -> bool:
        return True

    def ground_truth(self, resolution: float) -> VoxelLabels:
        """Occupied voxels of the room with their labels at ``resolution`` metres."""
        return ground_truth_voxels(self.room, resolution)
