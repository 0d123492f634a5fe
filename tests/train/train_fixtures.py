"""Data and constants of the training tests (imported by ``conftest.py`` and the tests)."""

from __future__ import annotations

import numpy as np

from evsmap.data import Frame, FrameList, Intrinsics

SIZE = (128, 192)
"""Input size of the test network: FEAGNet-V1 sees 1/64 of it at the deepest stage, 2x3 here.
At 64x96 that map is 1x1, where train-mode BatchNorm over a batch of 4 single pixels amplifies
gradients without bound (the eval-mode network then overflows)."""
CLASSES = 4
TINY = "feagnet-v1-test"
COLOURS = np.array([[200, 60, 60], [60, 200, 60], [60, 60, 200], [200, 200, 60]], np.uint8)


def colour_frames(n: int, *, height: int = SIZE[0], width: int = SIZE[1], seed: int = 0
                  ) -> FrameList:
    """``n`` frames: background (class 0) and three rectangles of classes 1-3, each class one
    colour plus uniform noise of +-25; the top two rows void; random depth (no information)."""
    rng = np.random.default_rng(seed)
    intr = Intrinsics(0.8 * width, 0.8 * width, width / 2 - 0.5, height / 2 - 0.5, width, height)
    frames = []
    for i in range(n):
        labels = np.zeros((height, width), np.uint8)
        for c in (1, 2, 3):
            y0, x0 = rng.integers(0, height * 3 // 4), rng.integers(0, width * 3 // 4)
            labels[y0:y0 + rng.integers(height // 6, height // 2),
                   x0:x0 + rng.integers(width // 6, width // 2)] = c
        rgb = COLOURS[labels].astype(np.int16) + rng.integers(-25, 26, (height, width, 3))
        labels[:2] = 255
        depth = rng.uniform(0.5, 4.0, (height, width)).astype(np.float32)
        frames.append(Frame(rgb=np.clip(rgb, 0, 255).astype(np.uint8), depth=depth,
                            intrinsics=intr, pose=np.eye(4), timestamp=float(i), labels=labels,
                            name=f"f{i}"))
    return FrameList("colours", intr, frames)
