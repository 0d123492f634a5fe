"""A run folder read back: ``run.json``, the records, and the paper's tables as frames.

:func:`read_run` and :func:`read_records` read the two kinds of file (every error one line
naming the file; records of older runs through the old-key mapping of
:mod:`evsmap.runner.record_keys`); :func:`load_run` joins them into a :class:`LoadedRun`, the
one view the report (:mod:`evsmap.report.build`), the comparison of runs
(:mod:`evsmap.report.compare`), the README's headline (:mod:`evsmap.report.headline`) and the
LaTeX tables (:mod:`evsmap.report.latex`) are built from. :func:`machine_text` and
:func:`commit_of` say which machine and commit a run measured.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

from evsmap.errors import DataFormatError
from evsmap.report.extra import extra_records
from evsmap.report.int8 import PREFIX as INT8_PREFIX
from evsmap.report.tables import table_frame
from evsmap.runner.detail import is_detail
from evsmap.runner.records import CellRecord
from evsmap.runner.runfile import RUN_FILE, RunFile
from evsmap.tables.schema import CellSpec, PaperTable, expand_all, load_tables


def read_run(run_dir: str | Path) -> dict[str, Any]:
    """``DIR/run.json`` as a dict of the keys it holds, read and checked by its one schema
    (:class:`~evsmap.runner.runfile.RunFile`).

    Raises:
        DataFormatError: the folder or the file is missing, or the file is not a run
            description; one line naming it.
    """
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise DataFormatError(f"{run_dir}: no such run folder")
    return RunFile.read(run_dir / RUN_FILE).model_dump(exclude_unset=True)


def read_records(run_dir: str | Path) -> list[CellRecord]:
    """Every ``DIR/records/*.json``, in file-name order.

    Raises:
        DataFormatError: a record is not JSON, not a cell record, or holds a value that is not
            a number; the message names the file.
    """
    folder = Path(run_dir) / "records"
    if not folder.is_dir():
        return []
    out = []
    for path in sorted(folder.glob("*.json")):
        try:
            data = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise DataFormatError(f"{path}: unreadable record ({exc})") from None
        except RecursionError:
            raise DataFormatError(f"{path}: unreadable record (nested too deeply)") from None
        rec = CellRecord.from_json(data, source=str(path))
        _check_record(rec, path)
        out.append(rec)
    return out


def _check_record(rec: CellRecord, path: Path) -> None:
    if not isinstance(rec.key, str) or not rec.key:
        raise DataFormatError(f"{path}: not a cell record (no key)")
    for name, kind in (("values", dict), ("details", dict), ("inputs", dict),
                       ("environment", dict), ("metrics", list), ("notes", list),
                       ("needs", list)):
        if not isinstance(getattr(rec, name), kind):
            raise DataFormatError(f"{path}: record {rec.key!r}: {name!r} must be a JSON "
                                  f"{kind.__name__}")
    for cid, value in rec.values.items():
        if (value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                   or not math.isfinite(value))):
            raise DataFormatError(f"{path}: record {rec.key!r}: value {cid!r} is not a finite "
                                  f"number ({value!r})")


@dataclass
class LoadedRun:
    """One run folder, read: its ``run.json``, its records (by key too), the paper's tables,
    the tables it covers and their frames (:func:`~evsmap.report.tables.table_frame`), the
    mapping runs beyond the tables (``extras``, the int8 and semantic-detail records apart)
    and the semantic-detail runs (``detail``)."""

    path: Path
    run: dict[str, Any]
    records: list[CellRecord]
    by_key: dict[str, CellRecord]
    tables: Mapping[str, PaperTable]
    specs: list[CellSpec]
    skipped: dict[str, str]
    table_ids: list[str]
    frames: dict[str, pd.DataFrame]
    extras: list[CellRecord]
    detail: list[CellRecord]

    @property
    def environment(self) -> dict[str, Any]:
        return dict(self.run.get("environment") or {})


def load_run(run_dir: str | Path) -> LoadedRun:
    """``run_dir`` read (:class:`LoadedRun`).

    Raises:
        DataFormatError: ``run.json`` or a record is missing or corrupt (names the file).
    """
    run_dir = Path(run_dir)
    run = read_run(run_dir)
    records = read_records(run_dir)
    by_key = {r.key: r for r in records}
    tables = load_tables()
    available = [str(a) for a in run.get("available") or []]
    specs = expand_all(tables, available=available)
    table_ids = [t for t in (run.get("tables") or []) if t in tables]
    table_ids += sorted({r.table for r in records if r.table in tables} - set(table_ids))
    if not table_ids:
        table_ids = sorted(tables)
    # the int8 records have their own section and CSV (evsmap.report.int8)
    extras = [r for r in extra_records(records) if not r.key.startswith(INT8_PREFIX)]
    # the semantic-detail runs have their own section (evsmap.report.detail): the other views
    # (the extra table, the plots) would show their rows as second copies of Table IV's systems
    detail = [r for r in extras if is_detail(r.row)]
    extras = [r for r in extras if not is_detail(r.row)]
    skipped = {str(pair[0]): str(pair[1]) for pair in run.get("skipped") or []
               if isinstance(pair, (list, tuple)) and len(pair) == 2}
    frames = {tid: table_frame(tables[tid], by_key, specs, skipped) for tid in table_ids}
    return LoadedRun(path=run_dir, run=run, records=records, by_key=by_key, tables=tables,
                     specs=list(specs), skipped=skipped, table_ids=table_ids, frames=frames,
                     extras=extras, detail=detail)


def commit_of(run: Mapping[str, Any]) -> str:
    """The evsmap commit a run measured (its environment's ``git_commit``; ``unknown``)."""
    env = run.get("environment") or {}
    return str(env.get("git_commit") or "unknown")


def machine_text(run: Mapping[str, Any]) -> str:
    """``AMD EPYC, avx512-vnni, 2 cores`` (and the GPU where the run used one): the machine a
    run measured, as a reader tells two apart."""
    env = run.get("environment") or {}
    text = (f"{env.get('cpu') or env.get('cpu_model') or '?'}, "
            f"{env.get('instruction_set') or '?'}, {env.get('cpus') or '?'} cores")
    gpu = gpu_of(run)
    return text + (f", {gpu}" if gpu else "")


def gpu_of(run: Mapping[str, Any]) -> str | None:
    """The GPU's model a run's cells ran on, ``None`` for a CPU run."""
    device = str((run.get("settings") or {}).get("device") or (run.get("context") or {})
                 .get("device") or "cpu")
    if device == "cpu":
        return None
    env = run.get("environment") or {}
    gpu = env.get("gpu")
    name = gpu.get("gpu") if isinstance(gpu, Mapping) else gpu
    return str(name or device)
