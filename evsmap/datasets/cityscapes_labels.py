"""The official Cityscapes label table (Cordts et al., CVPR 2016; cityscapesScripts
``helpers/labels.py``): label id -> train id and colours.

``*_gtFine_labelIds.png`` holds the ids 0..33; the 19 evaluated classes get train ids 0..18 and
every other id is ignored (train id 255, evsmap's void). ``license plate`` has id -1 and train id
-1 in the official table: it never appears in the label images (its pixels carry the car's id);
evsmap maps it to 255 as well.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from evsmap.data import VOID
from evsmap.errors import InvalidDataError


class CityscapesLabel(NamedTuple):
    name: str
    id: int
    train_id: int  # 255 = ignored in training and evaluation (the official table's value)
    category: str
    ignore_in_eval: bool
    color: tuple[int, int, int]


CITYSCAPES_LABELS: tuple[CityscapesLabel, ...] = (
    CityscapesLabel("unlabeled", 0, 255, "void", True, (0, 0, 0)),
    CityscapesLabel("ego vehicle", 1, 255, "void", True, (0, 0, 0)),
    CityscapesLabel("rectification border", 2, 255, "void", True, (0, 0, 0)),
    CityscapesLabel("out of roi", 3, 255, "void", True, (0, 0, 0)),
    CityscapesLabel("static", 4, 255, "void", True, (0, 0, 0)),
    CityscapesLabel("dynamic", 5, 255, "void", True, (111, 74, 0)),
    CityscapesLabel("ground", 6, 255, "void", True, (81, 0, 81)),
    CityscapesLabel("road", 7, 0, "flat", False, (128, 64, 128)),
    CityscapesLabel("sidewalk", 8, 1, "flat", False, (244, 35, 232)),
    CityscapesLabel("parking", 9, 255, "flat", True, (250, 170, 160)),
    CityscapesLabel("rail track", 10, 255, "flat", True, (230, 150, 140)),
    CityscapesLabel("building", 11, 2, "construction", False, (70, 70, 70)),
    CityscapesLabel("wall", 12, 3, "construction", False, (102, 102, 156)),
    CityscapesLabel("fence", 13, 4, "construction", False, (190, 153, 153)),
    CityscapesLabel("guard rail", 14, 255, "construction", True, (180, 165, 180)),
    CityscapesLabel("bridge", 15, 255, "construction", True, (150, 100, 100)),
    CityscapesLabel("tunnel", 16, 255, "construction", True, (150, 120, 90)),
    CityscapesLabel("pole", 17, 5, "object", False, (153, 153, 153)),
    CityscapesLabel("polegroup", 18, 255, "object", True, (153, 153, 153)),
    CityscapesLabel("traffic light", 19, 6, "object", False, (250, 170, 30)),
    CityscapesLabel("traffic sign", 20, 7, "object", False, (220, 220, 0)),
    CityscapesLabel("vegetation", 21, 8, "nature", False, (107, 142, 35)),
    CityscapesLabel("terrain", 22, 9, "nature", False, (152, 251, 152)),
    CityscapesLabel("sky", 23, 10, "sky", False, (70, 130, 180)),
    CityscapesLabel("person", 24, 11, "human", False, (220, 20, 60)),
    CityscapesLabel("rider", 25, 12, "human", False, (255, 0, 0)),
    CityscapesLabel("car", 26, 13, "vehicle", False, (0, 0, 142)),
    CityscapesLabel("truck", 27, 14, "vehicle", False, (0, 0, 70)),
    CityscapesLabel("bus", 28, 15, "vehicle", False, (0, 60, 100)),
    CityscapesLabel("caravan", 29, 255, "vehicle", True, (0, 0, 90)),
    CityscapesLabel("trailer", 30, 255, "vehicle", True, (0, 0, 110)),
    CityscapesLabel("train", 31, 16, "vehicle", False, (0, 80, 100)),
    CityscapesLabel("motorcycle", 32, 17, "vehicle", False, (0, 0, 230)),
    CityscapesLabel("bicycle", 33, 18, "vehicle", False, (119, 11, 32)),
    CityscapesLabel("license plate", -1, -1, "vehicle", True, (0, 0, 142)),
)
"""Every official label, in the official order."""

MAX_LABEL_ID = 33
"""Largest id in ``*_gtFine_labelIds.png``."""

LABEL_ID_TO_TRAIN_ID: dict[int, int] = {
    lab.id: (lab.train_id if 0 <= lab.train_id < 255 else VOID) for lab in CITYSCAPES_LABELS
}
"""Label id (0..33, -1) -> train id (0..18), 255 for every ignored label."""

_TRAIN = sorted((lab for lab in CITYSCAPES_LABELS if 0 <= lab.train_id < 255),
                key=lambda lab: lab.train_id)
CITYSCAPES19_NAMES: tuple[str, ...] = tuple(lab.name for lab in _TRAIN)
"""The 19 evaluated classes by train id."""
CITYSCAPES19_COLORS: np.ndarray = np.array([lab.color for lab in _TRAIN], dtype=np.uint8)
"""Official colours of the 19 train ids, ``uint8`` (19, 3)."""
CITYSCAPES19_COLORS.setflags(write=False)

_LUT = np.full(256, VOID, dtype=np.uint8)
for _id, _train in LABEL_ID_TO_TRAIN_ID.items():
    if _id >= 0:
        _LUT[_id] = _train
_LUT.setflags(write=False)


def label_ids_to_train_ids(ids: np.ndarray, where: Path | str = "labels") -> np.ndarray:
    """Map a ``uint8`` HxW label-id image to train ids (255 void); ids above 33 are an error."""
    ids = np.asarray(ids)
    if ids.size and int(ids.max()) > MAX_LABEL_ID:
        bad = ids > MAX_LABEL_ID
        raise InvalidDataError(f"{where}: label id {int(ids[bad].max())} outside "
                               f"0..{MAX_LABEL_ID} at {int(bad.sum())} pixels")
    return _LUT[ids.astype(np.uint8, copy=False)]
