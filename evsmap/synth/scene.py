"""Procedural indoor rooms made of labelled box meshes.

A room is an axis-aligned interior ``[0, L] x [0, W] x [0, H]`` (metres, z up) closed by floor,
ceiling and four walls, with doors, windows, pictures and curtains on the walls and furniture
placed along the walls and in the middle by seeded rejection sampling. Every part is an oriented
box (yaw about z) carrying an NYUv2-40 class id, an albedo and an instance id; composite furniture
(beds, chairs, desks, sofas, shelves with books) is several parts with their own classes.

Layout generators are registered by scene name in :data:`SCENES`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from evsmap.classes import NYU40
from evsmap.errors import UnknownNameError

# Base albedo (linear RGB in [0, 1]) per class; each instance varies it a little.
ALBEDO: dict[str, tuple[float, float, float]] = {
    "wall": (0.82, 0.78, 0.70), "floor": (0.55, 0.38, 0.24), "ceiling": (0.93, 0.93, 0.91),
    "cabinet": (0.60, 0.45, 0.30), "bed": (0.45, 0.30, 0.22), "chair": (0.30, 0.30, 0.34),
    "sofa": (0.25, 0.35, 0.55), "table": (0.50, 0.33, 0.20), "door": (0.70, 0.55, 0.38),
    "window": (0.62, 0.78, 0.90), "bookshelf": (0.42, 0.28, 0.18), "picture": (0.80, 0.35, 0.25),
    "counter": (0.80, 0.80, 0.78), "blinds": (0.85, 0.83, 0.75), "desk": (0.58, 0.42, 0.28),
    "shelves": (0.65, 0.62, 0.58), "curtain": (0.55, 0.20, 0.22), "dresser": (0.52, 0.36, 0.24),
    "pillow": (0.92, 0.90, 0.85), "mirror": (0.75, 0.80, 0.82), "floor mat": (0.45, 0.18, 0.15),
    "clothes": (0.30, 0.42, 0.30), "books": (0.60, 0.20, 0.30), "refrigerator": (0.88, 0.88, 0.90),
    "television": (0.08, 0.08, 0.09), "paper": (0.95, 0.95, 0.92), "towel": (0.35, 0.55, 0.70),
    "box": (0.68, 0.52, 0.34), "whiteboard": (0.96, 0.96, 0.96), "night stand": (0.48, 0.32, 0.20),
    "sink": (0.85, 0.86, 0.88), "lamp": (0.95, 0.88, 0.65), "bag": (0.20, 0.20, 0.40),
    "otherstructure": (0.70, 0.70, 0.70), "otherfurniture": (0.50, 0.45, 0.40),
    "otherprop": (0.40, 0.50, 0.35),
}


def _xyz(values: Iterable[float]) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in values)
    return x, y, z


@dataclass(frozen=True)
class Part:
    """One labelled box: centre, full size along its own axes, yaw (rad) about world z."""

    label: int
    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float
    albedo: tuple[float, float, float]
    instance: int

    def rotation(self) -> np.ndarray:
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def vertices(self) -> np.ndarray:
        """The 8 corners (8 x 3, float64) in world coordinates."""
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
        local = signs * (np.asarray(self.size) / 2.0)
        return local @ self.rotation().T + np.asarray(self.center)

    def to_local(self, points: np.ndarray) -> np.ndarray:
        """World points (N x 3) in the box frame (origin at the centre, axes along the size)."""
        return (np.asarray(points, float) - np.asarray(self.center)) @ self.rotation()

    def contains(self, points: np.ndarray, tol: float = 0.0) -> np.ndarray:
        """Whether each point lies inside the box grown by ``tol`` on every side."""
        local = np.abs(self.to_local(points))
        return np.all(local <= np.asarray(self.size) / 2.0 + tol, axis=1)


# 12 outward-facing triangles over the corner order of Part.vertices (index = 4x + 2y + z).
BOX_TRIANGLES = np.array([
    [0, 1, 3], [0, 3, 2],  # x-
    [4, 6, 7], [4, 7, 5],  # x+
    [0, 4, 5], [0, 5, 1],  # y-
    [2, 3, 7], [2, 7, 6],  # y+
    [0, 2, 6], [0, 6, 4],  # z-
    [1, 5, 7], [1, 7, 3],  # z+
], dtype=np.uint32)


@dataclass
class Room:
    """A generated room: interior size, parts, light positions."""

    name: str
    size: tuple[float, float, float]
    parts: list[Part] = field(default_factory=list)
    lights: list[tuple[float, float, float]] = field(default_factory=list)

    @property
    def labels(self) -> np.ndarray:
        return np.array([p.label for p in self.parts], dtype=np.uint8)


class _Builder:
    """Accumulates parts and 2D footprints while a layout is generated."""

    WALL_T = 0.12

    def __init__(self, name: str, rng: np.random.Generator, size: tuple[float, float, float]):
        self.rng = rng
        self.room = Room(name, size)
        self.footprints: list[tuple[float, float, float, float]] = []  # xmin, ymin, xmax, ymax
        self.keepout: list[tuple[float, float, float, float]] = []
        self.wall_spans: list[tuple[int, float, float, float]] = []  # wall, start, end, min z
        self._instance = 0

    # -- primitives ---------------------------------------------------------------------------
    def box(self, cls: str, center, size, yaw: float = 0.0, albedo=None, jitter: float = 0.08):
        base = np.asarray(ALBEDO[cls] if albedo is None else albedo)
        tint = np.clip(base * (1.0 + self.rng.uniform(-jitter, jitter, 3)), 0.02, 1.0)
        self._instance += 1
        self.room.parts.append(Part(
            NYU40[cls], _xyz(center), _xyz(size), float(yaw), _xyz(tint), self._instance,
        ))

    def shell(self) -> None:
        L, W, H = self.room.size
        t = self.WALL_T
        self.box("floor", (L / 2, W / 2, -t / 2), (L + 2 * t, W + 2 * t, t))
        self.box("ceiling", (L / 2, W / 2, H + t / 2), (L + 2 * t, W + 2 * t, t))
        self.box("wall", (-t / 2, W / 2, H / 2), (t, W + 2 * t, H))
        self.box("wall", (L + t / 2, W / 2, H / 2), (t, W + 2 * t, H))
        self.box("wall", (L / 2, -t / 2, H / 2), (L, t, H))
        self.box("wall", (L / 2, W + t / 2, H / 2), (L, t, H))
        n = 1 if L * W < 16 else 2
        for i in range(n):
            self.room.lights.append(((i + 0.5) * L / n, W / 2, H - 0.05))

    # -- wall frames ---------------------------------------------------------------------------
    def wall_length(self, wall: int) -> float:
        L, W, _ = self.room.size
        return L if wall in (0, 1) else W

    def wall_frame(self, wall: int, s: float, depth_off: float):
        """World (x, y) and yaw of a point ``s`` along ``wall`` and ``depth_off`` into the room.

        Walls: 0 = y=0 (faces +y), 1 = y=W (faces -y), 2 = x=0 (faces +x), 3 = x=L (faces -x).
        The returned yaw turns a part's local +y axis to face into the room.
        """
        L, W, _ = self.room.size
        if wall == 0:
            return s, depth_off, 0.0
        if wall == 1:
            return s, W - depth_off, np.pi
        if wall == 2:
            return depth_off, s, -np.pi / 2
        return L - depth_off, s, np.pi / 2

    def footprint(self, wall: int, s: float, width: float, depth: float, gap: float = 0.0):
        x, y, _ = self.wall_frame(wall, s, gap + depth / 2)
        if wall in (0, 1):
            return (x - width / 2, y - depth / 2, x + width / 2, y + depth / 2)
        return (x - depth / 2, y - width / 2, x + depth / 2, y + width / 2)

    @staticmethod
    def _overlap(a, b, clearance: float = 0.05) -> bool:
        return not (a[2] + clearance <= b[0] or b[2] + clearance <= a[0]
                    or a[3] + clearance <= b[1] or b[3] + clearance <= a[1])

    def free(self, rect) -> bool:
        L, W, _ = self.room.size
        if rect[0] < -1e-9 or rect[1] < -1e-9 or rect[2] > L + 1e-9 or rect[3] > W + 1e-9:
            return False
        return not any(self._overlap(rect, r) for r in self.footprints + self.keepout)

    def place_on_wall(self, width: float, depth: float, height: float, gap: float = 0.0,
                      walls=(0, 1, 2, 3), tries: int = 60):
        """Find a free spot against a wall; returns (wall, s) or None."""
        for _ in range(tries):
            wall = int(self.rng.choice(walls))
            length = self.wall_length(wall)
            if length < width + 0.1:
                continue
            s = float(self.rng.uniform(width / 2 + 0.05, length - width / 2 - 0.05))
            rect = self.footprint(wall, s, width, depth, gap)
            if not self.free(rect):
                continue
            if any(w == wall and height > zmin and s + width / 2 > a and s - width / 2 < b
                   for w, a, b, zmin in self.wall_spans):
                continue
            self.footprints.append(rect)
            return wall, s
        return None

    def reserve_wall_span(self, wall: int, start: float, end: float, zmin: float) -> None:
        """Forbid floor items taller than ``zmin`` in front of a wall span (windows)."""
        self.wall_spans.append((wall, start, end, zmin))

    def local_box(self, cls, wall, s, along, out, z, size, gap=0.0, **kw):
        """A box positioned in the wall frame: ``along`` the wall, ``out`` into the room (from
        the wall surface plus ``gap``), ``z`` the bottom height; size = (width, depth, height)."""
        x, y, yaw = self.wall_frame(wall, s + along if wall in (0, 3) else s - along,
                                    gap + out + size[1] / 2)
        self.box(cls, (x, y, z + size[2] / 2), size, yaw, **kw)

    # -- wall fixtures -------------------------------------------------------------------------
    def door(self) -> None:
        wall = int(self.rng.integers(4))
        length = self.wall_length(wall)
        s = float(self.rng.uniform(0.7, length - 0.7))
        self.local_box("door", wall, s, 0.0, 0.0, 0.0, (0.9, 0.04, 2.05))
        self.keepout.append(self.footprint(wall, s, 1.0, 1.0))

    def window(self, wall: int | None = None, curtains: bool = True) -> None:
        for _ in range(30):
            w = int(self.rng.integers(4)) if wall is None else wall
            length = self.wall_length(w)
            width = float(self.rng.uniform(0.9, min(1.6, length - 1.2)))
            s = float(self.rng.uniform(width / 2 + 0.5, length - width / 2 - 0.5))
            span = (s - width / 2 - 0.35, s + width / 2 + 0.35)
            if any(w == ww and span[1] > a and span[0] < b for ww, a, b, _ in self.wall_spans):
                continue
            if any(self._overlap(self.footprint(w, s, width + 0.7, 0.3), r) for r in self.keepout):
                continue
            self.local_box("window", w, s, 0.0, 0.0, 0.9, (width, 0.03, 1.2))
            if curtains:
                for side in (-1, 1):
                    self.local_box("curtain", w, s, side * (width / 2 + 0.15), 0.04, 0.05,
                                   (0.3, 0.06, 2.2))
            else:
                self.local_box("blinds", w, s, 0.0, 0.05, 1.6, (width + 0.1, 0.04, 0.55))
            self.reserve_wall_span(w, *span, zmin=0.85)
            return

    def wall_item(self, cls: str, width: float, height: float, z: float, thick: float = 0.02):
        for _ in range(30):
            w = int(self.rng.integers(4))
            length = self.wall_length(w)
            if length < width + 0.4:
                continue
            s = float(self.rng.uniform(width / 2 + 0.2, length - width / 2 - 0.2))
            if any(w == ww and s + width / 2 > a and s - width / 2 < b
                   for ww, a, b, _ in self.wall_spans):
                continue
            if any(self._overlap(self.footprint(w, s, width, 0.3), r) for r in self.keepout):
                continue
            self.local_box(cls, w, s, 0.0, 0.0, z, (width, thick, height))
            self.reserve_wall_span(w, s - width / 2, s + width / 2, zmin=z - 0.05)
            return

    # -- furniture -----------------------------------------------------------------------------
    def bed(self) -> None:
        width, length = float(self.rng.uniform(1.4, 1.8)), float(self.rng.uniform(1.95, 2.1))
        spot = self.place_on_wall(width + 1.1, length, 0.9)
        if spot is None:
            return
        wall, s = spot
        self.local_box("bed", wall, s, 0.0, 0.0, 0.0, (width, length, 0.45))
        self.local_box("otherfurniture", wall, s, 0.0, 0.0, 0.0, (width, 0.06, 0.9))
        for side in (-1, 1) if width > 1.5 else (0,):
            self.local_box("pillow", wall, s, side * width / 4, 0.1, 0.45,
                           (min(0.6, width / 2 - 0.1), 0.4, 0.14))
        for side in (-1, 1):
            along = side * (width / 2 + 0.3)
            self.local_box("night stand", wall, s, along, 0.0, 0.0, (0.45, 0.4, 0.55))
            if side == 1 or self.rng.random() < 0.5:
                self.lamp_on(wall, s, along, 0.55)

    def lamp_on(self, wall, s, along, z) -> None:
        self.local_box("lamp", wall, s, along, 0.12, z, (0.12, 0.12, 0.3))
        self.local_box("lamp", wall, s, along, 0.06, z + 0.3, (0.26, 0.26, 0.2))

    def floor_lamp(self) -> None:
        spot = self.place_on_wall(0.4, 0.4, 1.7, gap=0.05)
        if spot is None:
            return
        wall, s = spot
        self.local_box("lamp", wall, s, 0.0, 0.05, 0.0, (0.3, 0.3, 0.03), gap=0.05)
        self.local_box("lamp", wall, s, 0.0, 0.18, 0.03, (0.04, 0.04, 1.4), gap=0.05)
        self.local_box("lamp", wall, s, 0.0, 0.03, 1.43, (0.34, 0.34, 0.28), gap=0.05)

    def cabinet(self, cls: str = "cabinet", width=(0.8, 1.4), depth=(0.45, 0.6),
                height=(0.8, 2.1)) -> None:
        w, d, h = (float(self.rng.uniform(*r)) for r in (width, depth, height))
        spot = self.place_on_wall(w, d, h)
        if spot is None:
            return
        wall, s = spot
        self.local_box(cls, wall, s, 0.0, 0.0, 0.0, (w, d, h))
        if cls == "dresser" and self.rng.random() < 0.7:
            self.local_box("television", wall, s, 0.0, 0.15, h, (min(w - 0.1, 1.0), 0.08, 0.6))
        elif h < 1.2 and self.rng.random() < 0.6:
            self.local_box("box", wall, s, float(self.rng.uniform(-w / 4, w / 4)), 0.1, h,
                           (0.35, 0.3, 0.25))

    def bookshelf(self) -> None:
        w, d, h = float(self.rng.uniform(0.8, 1.2)), 0.35, float(self.rng.uniform(1.6, 2.0))
        spot = self.place_on_wall(w, d, h)
        if spot is None:
            return
        wall, s = spot
        self.local_box("bookshelf", wall, s, 0.0, 0.0, 0.0, (w, d, h))
        rows = int(h // 0.4)
        for r in range(rows):
            z = 0.05 + r * 0.4
            pos = -w / 2 + 0.05
            while pos < w / 2 - 0.12:
                bw = float(self.rng.uniform(0.03, 0.07)) * int(self.rng.integers(2, 6))
                bw = min(bw, w / 2 - 0.05 - pos)
                bh = float(self.rng.uniform(0.2, 0.32))
                if self.rng.random() < 0.8:
                    self.local_box("books", wall, s, pos + bw / 2, d, z, (bw, 0.03, bh),
                                   jitter=0.5)
                pos += bw + 0.01

    def shelves(self) -> None:
        w = float(self.rng.uniform(0.8, 1.4))
        for _ in range(20):
            wall = int(self.rng.integers(4))
            length = self.wall_length(wall)
            s = float(self.rng.uniform(w / 2 + 0.1, length - w / 2 - 0.1))
            z = float(self.rng.uniform(1.3, 1.7))
            if any(wall == ww and s + w / 2 > a and s - w / 2 < b
                   for ww, a, b, _ in self.wall_spans):
                continue
            for k in range(2):
                self.local_box("shelves", wall, s, 0.0, 0.0, z + 0.35 * k, (w, 0.25, 0.025))
                self.local_box("otherprop", wall, s, float(self.rng.uniform(-w / 3, w / 3)), 0.05,
                               z + 0.35 * k + 0.025, (0.12, 0.12, 0.18), jitter=0.6)
            self.reserve_wall_span(wall, s - w / 2, s + w / 2, zmin=z - 0.05)
            return

    def desk_with_chair(self) -> None:
        w, d = float(self.rng.uniform(1.1, 1.5)), float(self.rng.uniform(0.6, 0.75))
        spot = self.place_on_wall(w, d + 0.8, 0.8)
        if spot is None:
            return
        wall, s = spot
        self.table_parts("desk", wall, s, 0.0, 0.0, w, d, 0.75)
        self.local_box("television", wall, s, 0.0, 0.1, 0.75, (0.55, 0.05, 0.35))
        self.local_box("paper", wall, s, w / 4, 0.35, 0.75, (0.21, 0.297, 0.005))
        self.chair(wall, s, 0.0, d + 0.05)

    def table_parts(self, cls, wall, s, along, out, w, d, h) -> None:
        self.local_box(cls, wall, s, along, out, h - 0.04, (w, d, 0.04))
        for sa in (-1, 1):
            for so in (0, 1):
                self.local_box(cls, wall, s, along + sa * (w / 2 - 0.04),
                               out + so * (d - 0.06), 0.0, (0.05, 0.05, h - 0.04))

    def chair(self, wall, s, along, out) -> None:
        self.local_box("chair", wall, s, along, out, 0.42, (0.45, 0.45, 0.04))
        self.local_box("chair", wall, s, along, out + 0.41, 0.46, (0.45, 0.04, 0.45))
        for sa in (-1, 1):
            for so in (0, 1):
                self.local_box("chair", wall, s, along + sa * 0.19, out + so * 0.39, 0.0,
                               (0.04, 0.04, 0.42))

    def sofa(self) -> None:
        w = float(self.rng.uniform(1.8, 2.4))
        spot = self.place_on_wall(w, 0.9 + 0.9, 0.85)
        if spot is None:
            return
        wall, s = spot
        self.local_box("sofa", wall, s, 0.0, 0.0, 0.0, (w, 0.9, 0.42))
        self.local_box("sofa", wall, s, 0.0, 0.0, 0.42, (w, 0.22, 0.45))
        for side in (-1, 1):
            self.local_box("sofa", wall, s, side * (w / 2 - 0.1), 0.22, 0.42, (0.2, 0.68, 0.2))
            self.local_box("pillow", wall, s, side * (w / 4), 0.22, 0.42, (0.4, 0.14, 0.38))
        self.local_box("table", wall, s, 0.0, 1.3, 0.0, (1.0, 0.55, 0.42))
        self.footprints.append(self.footprint(wall, s, 1.1, 0.7, gap=1.25))
        if self.rng.random() < 0.8:
            self.local_box("floor mat", wall, s, 0.0, 0.95, 0.0, (min(w, 2.0), 1.4, 0.01))

    def kitchen_run(self) -> None:
        w = float(self.rng.uniform(2.2, 3.2))
        spot = self.place_on_wall(w, 0.6 + 0.6, 2.2)
        if spot is None:
            return
        wall, s = spot
        self.local_box("cabinet", wall, s, 0.0, 0.0, 0.0, (w, 0.58, 0.86))
        self.local_box("counter", wall, s, 0.0, 0.0, 0.86, (w, 0.62, 0.04))
        self.local_box("sink", wall, s, float(self.rng.uniform(-w / 4, w / 4)), 0.1, 0.9,
                       (0.6, 0.42, 0.06))
        self.local_box("cabinet", wall, s, 0.0, 0.0, 1.5, (w, 0.35, 0.7))
        fridge = self.place_on_wall(0.75, 0.7, 1.85)
        if fridge is not None:
            fw, fs = fridge
            self.local_box("refrigerator", fw, fs, 0.0, 0.0, 0.0, (0.72, 0.68, 1.85))

    def dining_table(self) -> None:
        L, W, _ = self.room.size
        w, d = float(self.rng.uniform(1.2, 1.6)), float(self.rng.uniform(0.8, 0.9))
        for _ in range(40):
            cx = float(self.rng.uniform(L * 0.3, L * 0.7))
            cy = float(self.rng.uniform(W * 0.3, W * 0.7))
            rect = (cx - w / 2 - 0.5, cy - d / 2 - 0.5, cx + w / 2 + 0.5, cy + d / 2 + 0.5)
            if self.free(rect):
                break
        else:
            return
        self.footprints.append(rect)
        self.box("table", (cx, cy, 0.73), (w, d, 0.04))
        for sx in (-1, 1):
            for sy in (-1, 1):
                self.box("table", (cx + sx * (w / 2 - 0.05), cy + sy * (d / 2 - 0.05), 0.355),
                         (0.05, 0.05, 0.71))
        for sx in (-1, 1):
            for sy in (-1, 1):
                x, y = cx + sx * w / 4, cy + sy * (d / 2 + 0.3)
                self.box("chair", (x, y, 0.44), (0.44, 0.44, 0.04))
                self.box("chair", (x, y + sy * 0.2, 0.7), (0.44, 0.04, 0.48))
                for lx in (-1, 1):
                    for ly in (-1, 1):
                        self.box("chair", (x + lx * 0.19, y + ly * 0.19, 0.21), (0.04, 0.04, 0.42))

    def clutter(self, n: int) -> None:
        for _ in range(n):
            cls = str(self.rng.choice(["box", "bag", "clothes", "otherprop"]))
            size = {"box": (0.45, 0.35, 0.3), "bag": (0.35, 0.2, 0.4),
                    "clothes": (0.5, 0.4, 0.08), "otherprop": (0.25, 0.25, 0.35)}[cls]
            spot = self.place_on_wall(size[0], size[1], size[2], gap=0.02)
            if spot is not None:
                self.local_box(cls, spot[0], spot[1], 0.0, 0.0, 0.0, size, gap=0.02, jitter=0.4)


def _bedroom(b: _Builder) -> None:
    b.door()
    b.window()
    b.bed()
    b.cabinet("cabinet", width=(0.9, 1.4), height=(1.9, 2.1))
    b.cabinet("dresser", width=(1.0, 1.4), depth=(0.45, 0.5), height=(0.75, 0.9))
    b.desk_with_chair()
    b.wall_item("picture", 0.7, 0.5, 1.45)
    b.wall_item("mirror", 0.5, 0.9, 1.0)
    b.shelves()
    b.clutter(3)


def _living_room(b: _Builder) -> None:
    b.door()
    b.window()
    b.window(curtains=False)
    b.sofa()
    b.bookshelf()
    b.cabinet("cabinet", width=(1.2, 1.8), depth=(0.4, 0.5), height=(0.5, 0.7))
    b.floor_lamp()
    b.wall_item("picture", 0.9, 0.6, 1.4)
    b.wall_item("picture", 0.5, 0.4, 1.5)
    b.shelves()
    b.clutter(2)


def _office(b: _Builder) -> None:
    b.door()
    b.window(curtains=False)
    b.desk_with_chair()
    b.desk_with_chair()
    b.bookshelf()
    b.bookshelf()
    b.cabinet("cabinet", width=(0.8, 1.0), height=(1.0, 1.3))
    b.wall_item("whiteboard", 1.5, 1.0, 1.0)
    b.floor_lamp()
    b.clutter(4)


def _kitchen(b: _Builder) -> None:
    b.door()
    b.window()
    b.kitchen_run()
    b.dining_table()
    b.cabinet("cabinet", width=(0.8, 1.2), height=(1.8, 2.1))
    b.wall_item("picture", 0.6, 0.45, 1.5)
    b.shelves()
    b.clutter(2)


SCENES: dict[str, tuple[Callable[[_Builder], None], tuple[float, float], tuple[float, float]]] = {
    # name: (layout, length range, width range)
    "bedroom": (_bedroom, (4.2, 5.5), (3.6, 4.6)),
    "living_room": (_living_room, (5.0, 6.5), (4.0, 5.2)),
    "office": (_office, (4.5, 6.0), (3.8, 5.0)),
    "kitchen": (_kitchen, (4.2, 5.5), (3.6, 4.6)),
}
DEFAULT_SCENE = "living_room"


def build_room(scene: str = DEFAULT_SCENE, *, seed: int = 0) -> Room:
    """Generate the room ``scene`` with the random stream of ``seed`` (same seed, same room)."""
    if scene not in SCENES:
        import difflib

        close = difflib.get_close_matches(scene, list(SCENES), n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise UnknownNameError(
            f"unknown scene {scene!r}{hint} (known: {', '.join(sorted(SCENES))})"
        )
    layout, lrange, wrange = SCENES[scene]
    rng = np.random.default_rng([seed, sorted(SCENES).index(scene)])
    size = (float(rng.uniform(*lrange)), float(rng.uniform(*wrange)), float(rng.uniform(2.5, 2.8)))
    b = _Builder(scene, rng, size)
    b.shell()
    layout(b)
    return b.room
