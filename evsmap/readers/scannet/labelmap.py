"""ScanNet's label table (``scannetv2-labels.combined.tsv``) and its official split files.

The table is tab-separated with a header row; the columns read here are ``id`` (the ScanNet
label id its 2D label images hold), ``raw_category`` and ``nyu40id`` (0: none of the 40), as
ScanNet's ``BenchmarkScripts/util.py`` (``read_label_mapping``) and
``2d_helpers/convert_scannet_label_image.py`` read them. The split files
(``scannetv2_train.txt``, ``scannetv2_val.txt``, ``scannetv2_test.txt`` in ScanNet's
``Tasks/Benchmark``) list one scene id (``scene0000_00``) a line.
"""

from __future__ import annotations

import csv
import io
import os
import re
from pathlib import Path

import numpy as np

from evsmap.data import VOID
from evsmap.errors import DataFormatError
from evsmap.readers.scannet.mesh import nyu40_classes

LABELS_TSV = "scannetv2-labels.combined.tsv"
SPLITS = ("train", "val", "test")
SPLIT_FILE = "scannetv2_{}.txt"
SCENE_ID = re.compile(r"^scene\d{4}_\d{2}$")
MAX_LABEL_ID = 65535
"""ScanNet's 2D label images are 16-bit: the ids the table can map."""


def read_label_table(path: str | os.PathLike[str]) -> np.ndarray:
    """``scannetv2-labels.combined.tsv`` as a lookup: ``uint8`` array of 65536 entries, the
    0-based NYU40 class of each ScanNet label id (:data:`VOID` where the id is not in the table
    or maps to none of the 40).

    Raises:
        DataFormatError: unreadable, no ``id``/``nyu40id`` column, a value that is not an id,
            an id listed twice with different classes.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise DataFormatError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: cannot read ({exc})") from None
    rows = csv.DictReader(io.StringIO(text), delimiter="\t")
    columns = rows.fieldnames or []
    for need in ("id", "nyu40id"):
        if need not in columns:
            raise DataFormatError(f"{path}: no '{need}' column (the header has "
                                  f"{', '.join(columns[:12]) or 'nothing'})")
    table = np.full(MAX_LABEL_ID + 1, VOID, dtype=np.uint8)
    seen: dict[int, int] = {}
    try:
        for line, row in enumerate(rows, start=2):
            label_id, nyu = _integer(row, "id", path, line), _integer(row, "nyu40id", path, line)
            if not 0 <= label_id <= MAX_LABEL_ID:
                raise DataFormatError(f"{path}: line {line}: id {label_id} outside 0..65535")
            cls = int(nyu40_classes(np.array([nyu]), f"{path}: line {line}")[0])
            if seen.setdefault(label_id, cls) != cls:
                raise DataFormatError(f"{path}: line {line}: id {label_id} listed again with "
                                      f"another nyu40id")
            table[label_id] = cls
    except csv.Error as exc:
        raise DataFormatError(f"{path}: not a tab-separated table ({exc})") from None
    if not seen:
        raise DataFormatError(f"{path}: the table has no rows")
    return table


def _integer(row: dict, column: str, path: Path, line: int) -> int:
    text = (row.get(column) or "").strip()
    try:
        return int(text)
    except ValueError:
        raise DataFormatError(f"{path}: line {line}: {column} {text[:40]!r} is not an "
                              f"integer") from None


def read_split(path: str | os.PathLike[str]) -> list[str]:
    """The scene ids of a split file, in its order.

    Raises:
        DataFormatError: unreadable, or a line that is not a scene id.
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()
    except FileNotFoundError:
        raise DataFormatError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(f"{path}: cannot read ({exc})") from None
    scenes = []
    for n, raw in enumerate(lines, start=1):
        text = raw.strip()
        if not text:
            continue
        if not SCENE_ID.match(text):
            raise DataFormatError(f"{path}: line {n}: {text[:40]!r} is not a scene id "
                                  f"(sceneNNNN_NN)")
        scenes.append(text)
    return scenes


__all__ = ["LABELS_TSV", "SCENE_ID", "SPLITS", "SPLIT_FILE", "read_label_table", "read_split"]
