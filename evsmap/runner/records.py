"""One record per cell, stored as JSON as soon as the cell finishes.

A record holds what was run (the cell's inputs), what came out (values in base units: parameter
count, MAC count, frames per second, hertz, bytes, mIoU as a fraction), why a cell could not be
measured (``status = "na"`` with ``needs``), or the error of a failed cell, and the environment
it ran in. The report layer formats records; nothing here formats numbers.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from evsmap.errors import DataFormatError
from evsmap.fileio import atomic_write
from evsmap.runner.record_keys import older_size_readings, renamed_keys

STATUSES = ("ok", "na", "error")

NEEDS_TEXT = {
    "dataset": "needs the {} dataset",
    "weights": "needs trained weights ({})",
    "hardware": "needs {} hardware",
}


FETCHABLE = {"tum": "tum-fr1-xyz"}
"""Datasets a missing cell can get from ``evsmap datasets fetch`` (the sample's name)."""


CHECKED = ("scannet",)
"""Datasets evsmap cannot download (their terms need an agreement): ``evsmap datasets check``
says how to obtain one and checks a copy."""


def needs_text(needs: list[str] | tuple[str, ...]) -> str:
    """``"n/a - needs the nyuv2 dataset, needs trained weights (feagnet-v2@nyuv2)"``."""
    parts = []
    for need in needs:
        kind, _, what = need.partition(":")
        text = NEEDS_TEXT.get(kind, "needs {}").format(what or kind)
        if kind == "dataset" and what in FETCHABLE:
            text += f" (`evsmap datasets fetch {FETCHABLE[what]}`)"
        elif kind == "dataset" and what in CHECKED:
            text += f" under the data root (`evsmap datasets check {what}` says how to get it)"
        parts.append(text)
    return "n/a - " + ", ".join(parts) if parts else "n/a"


@dataclass
class CellRecord:
    """The outcome of one cell.

    Attributes:
        key: the cell's :attr:`evsmap.tables.CellSpec.key` (``extra/...`` for the measurements
            beyond the paper's tables).
        table, row, label, kind: where the cell belongs (``kind``: accuracy, complexity, speed,
            mapping).
        metrics: the column ids the cell fills.
        status: ``ok`` (values measured), ``na`` (cannot be measured here: see ``needs`` and
            ``reason``) or ``error`` (the run failed: see ``error``).
        values: column id -> measured value in base units (only for ``ok``).
        notes: how the values were obtained, one sentence each (the sequence measured on, the
            labels used, the backend).
        needs: requirement strings missing here (``dataset:X``, ``weights:S@D``, ``hardware:H``).
        reason: a one-line explanation for ``na`` cells ("n/a - needs the nyuv2 dataset").
        error: the error message of a failed cell.
        details: the full measurement records (speed IQR, per-frame times, map statistics, 3D
            map quality, ...) as plain JSON.
        inputs: the cell's configuration (segmenter and updater specs, datasets, sizes).
        environment: CPU model, threads, library versions, git commit, host.
        started, seconds: UTC start time (ISO 8601) and wall time.
        cell_peak_rss_bytes: the peak resident memory of the process while the cell ran
            (Linux: the peak is reset when the cell starts; 0: not measured).
        around: the time around a timed cell, seconds (:mod:`evsmap.runner.accounting`:
            ``wall_s`` the run waited for it, split into ``start_s``, ``setup_s``, ``cell_s``,
            ``finish_s``, ``return_s``, ``retry_s``); for an untimed cell its share of its
            pool's time (``wall_s``, ``pooled``); empty in records of older runs.
    """

    key: str
    table: str
    row: str
    label: str
    kind: str
    metrics: list[str]
    status: str
    values: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    needs: list[str] = field(default_factory=list)
    reason: str = ""
    error: str = ""
    details: dict[str, Any] = field(default_factory=dict)
    inputs: dict[str, Any] = field(default_factory=dict)
    environment: dict[str, Any] = field(default_factory=dict)
    started: str = ""
    seconds: float = 0.0
    cell_peak_rss_bytes: int = 0
    around: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"record {self.key!r}: status must be one of {STATUSES}, "
                             f"got {self.status!r}")

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, source: str = "record") -> CellRecord:
        names = {f.name for f in fields(cls)}
        unknown = sorted((k for k in data if k not in names), key=str)
        if unknown:
            raise DataFormatError(f"{source}: not a cell record (unknown field {unknown[0]!r})")
        try:
            return cls(**data)
        except (TypeError, ValueError) as exc:
            raise DataFormatError(f"{source}: not a cell record ({exc})") from None

    @classmethod
    def from_json(cls, data: Any, *, source: str) -> CellRecord:
        """A record read from a file: ``data`` must be a JSON object whose fields have their
        JSON types (strings, lists of strings, objects, a number of seconds).

        Raises:
            DataFormatError: ``source: not a cell record (what is wrong)``, one line.
        """
        if not isinstance(data, dict):
            raise DataFormatError(f"{source}: not a cell record (a JSON {type(data).__name__})")
        for name, value in data.items():
            kind = _JSON_TYPES.get(name)
            if kind is None:
                continue
            bad = not isinstance(value, kind) or isinstance(value, bool) and kind is not bool
            if not bad and kind is list and name in _STRING_LISTS:
                bad = not all(isinstance(v, str) for v in value)
            if bad:
                what = "a list of strings" if name in _STRING_LISTS else _KIND_NAMES[kind]
                raise DataFormatError(f"{source}: not a cell record ({name!r} must be {what}, "
                                      f"not {type(value).__name__})")
        data = {k: renamed_keys(v) if k in _RENAMED else v  # old runs' keys (rates, leaf size)
                for k, v in data.items()}
        if str(data.get("key", "")).startswith("extra/mapping/"):  # old runs' size readings
            data["values"] = older_size_readings(data.get("values") or {},
                                                 data.get("inputs") or {},
                                                 data.get("details") or {})
        return cls.from_dict(data, source=source)


_JSON_TYPES: dict[str, Any] = {
    "key": str, "table": str, "row": str, "label": str, "kind": str, "status": str,
    "reason": str, "error": str, "started": str, "seconds": (int, float),
    "cell_peak_rss_bytes": int,
    "metrics": list, "notes": list, "needs": list,
    "values": dict, "details": dict, "inputs": dict, "environment": dict}
_STRING_LISTS = ("metrics", "notes", "needs")
_RENAMED = ("inputs", "values", "details")
_KIND_NAMES = {str: "a string", (int, float): "a number", int: "an integer", list: "a list",
               dict: "an object"}


def _file_name(key: str) -> str:
    """A file name for ``key``: readable, unique (a hash suffix keeps distinct keys apart)."""
    import hashlib

    safe = re.sub(r"[^A-Za-z0-9_.+=-]+", "_", key).strip("_")[:150]
    return f"{safe}-{hashlib.sha1(key.encode()).hexdigest()[:10]}.json"


class RecordStore:
    """The records of one run: ``DIR/records/<key>.json``, each written atomically."""

    def __init__(self, root: str | os.PathLike[str]) -> None:
        self.root = Path(root)
        self.folder = self.root / "records"

    def path(self, key: str) -> Path:
        return self.folder / _file_name(key)

    def write(self, record: CellRecord) -> Path:
        self.folder.mkdir(parents=True, exist_ok=True)
        target = self.path(record.key)
        with atomic_write(target, "w") as fh:
            json.dump(record.as_dict(), fh, indent=1, default=_json_default)
        return target

    def get(self, key: str) -> CellRecord | None:
        path = self.path(key)
        if not path.is_file():
            return None
        return self._read(path)

    def _read(self, path: Path) -> CellRecord:
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise DataFormatError(f"{path}: unreadable record ({exc})") from None
        except RecursionError:
            raise DataFormatError(f"{path}: unreadable record (nested too deeply)") from None
        return CellRecord.from_json(data, source=str(path))

    def __iter__(self) -> Iterator[CellRecord]:
        if not self.folder.is_dir():
            return iter(())
        return (self._read(p) for p in sorted(self.folder.glob("*.json")))

    def all(self) -> list[CellRecord]:
        return list(self)


def _json_default(value: Any) -> Any:
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")

