"""Label sets: the NYUv2 40-class set (Gupta et al. 2013 mapping, standard order) used by the
synthetic scenes, and display colours."""

from __future__ import annotations

import numpy as np

NYU40_CLASSES: tuple[str, ...] = (
    "wall", "floor", "cabinet", "bed", "chair", "sofa", "table", "door", "window", "bookshelf",
    "picture", "counter", "blinds", "desk", "shelves", "curtain", "dresser", "pillow", "mirror",
    "floor mat", "clothes", "ceiling", "books", "refrigerator", "television", "paper", "towel",
    "shower curtain", "box", "whiteboard", "person", "night stand", "toilet", "sink", "lamp",
    "bathtub", "bag", "otherstructure", "otherfurniture", "otherprop",
)
"""Class names by id (0-based; 255 is void)."""

NYU40 = {name: i for i, name in enumerate(NYU40_CLASSES)}
"""Class id by name."""


def palette(num_classes: int) -> np.ndarray:
    """Distinct display colours, ``uint8`` (num_classes, 3), the same on every call.

    Colours walk the hue circle by the golden angle with alternating value, so neighbouring ids
    never look alike.
    """
    i = np.arange(num_classes, dtype=np.float64)
    hue = (i * 0.618033988749895) % 1.0
    sat = 0.55 + 0.35 * ((i % 3) / 2.0)
    val = 0.95 - 0.3 * (i % 2)
    h6 = hue * 6.0
    c = val * sat
    x = c * (1 - np.abs(h6 % 2 - 1))
    m = val - c
    sector = np.floor(h6).astype(int) % 6
    zeros = np.zeros_like(c)
    table = np.stack([
        np.stack([c, x, zeros], 1), np.stack([x, c, zeros], 1), np.stack([zeros, c, x], 1),
        np.stack([zeros, x, c], 1), np.stack([x, zeros, c], 1), np.stack([c, zeros, x], 1),
    ], 0)
    rgb = table[sector, np.arange(num_classes)] + m[:, None]
    return np.round(rgb * 255).astype(np.uint8)


def colorize(labels: np.ndarray, num_classes: int = len(NYU40_CLASSES)) -> np.ndarray:
    """HxWx3 ``uint8`` picture of a label image; void (255) is black."""
    lut = np.zeros((256, 3), dtype=np.uint8)
    lut[:num_classes] = palette(num_classes)
    return lut[labels]


SUNRGBD37_CLASSES: tuple[str, ...] = (
    "wall", "floor", "cabinet", "bed", "chair", "sofa", "table", "door", "window", "bookshelf",
    "picture", "counter", "blinds", "desk", "shelves", "curtain", "dresser", "pillow", "mirror",
    "floor mat", "clothes", "ceiling", "books", "fridge", "tv", "paper", "towel",
    "shower curtain", "box", "whiteboard", "person", "night stand", "toilet", "sink", "lamp",
    "bathtub", "bag",
)
"""SUN RGB-D's 37 classes (Song et al. 2015) by id (label value - 1 in ``SUNRGBD2Dseg.mat``): the
toolbox's ``seg37list`` with ``_`` as a space. The same classes, in the same order, as the first
37 of the NYUv2-40 set."""

CITYSCAPES19_CLASSES: tuple[str, ...] = (
    "road", "sidewalk", "building", "wall", "fence", "pole", "traffic light", "traffic sign",
    "vegetation", "terrain", "sky", "person", "rider", "car", "truck", "bus", "train",
    "motorcycle", "bicycle",
)
"""Cityscapes' 19 evaluation classes by train id (Cordts et al. 2016)."""


def class_names_for(num_classes: int, *, outdoor: bool = False) -> tuple[str, ...]:
    """The standard label set of that size (40 NYUv2, 37 SUN RGB-D, 19 Cityscapes), else
    ``class_0 ... class_{n-1}``. ``outdoor`` prefers Cityscapes when sizes could clash."""
    known = {40: NYU40_CLASSES, 37: SUNRGBD37_CLASSES, 19: CITYSCAPES19_CLASSES}
    if num_classes in known and (num_classes == 19 or not outdoor):
        return known[num_classes]
    return tuple(f"class_{i}" for i in range(num_classes))
