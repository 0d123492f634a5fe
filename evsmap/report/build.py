"""Build a run folder's report from what the runner stored (no measuring).

Reads ``DIR/run.json`` and ``DIR/records/*.json`` and writes into ``DIR``:

* ``tableN.md`` / ``tableN.csv`` per table of the run (see :mod:`evsmap.report.tables`),
  ``extra.csv`` with the measurements beyond the paper;
* ``networks.png``, ``mapping.png``, ``qualitative.png`` where there is data for them (see
  :mod:`evsmap.report.plots`);
* ``index.md``: the run, its environment, what was available, cell counts per table and links.

The folder is read by :func:`evsmap.report.run_data.load_run` (:func:`read_run` and
:func:`read_records` are named here too).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pandas as pd

from evsmap.fileio import atomic_write_text
from evsmap.report import plots
from evsmap.report.claims import claims_markdown, relative_markdown
from evsmap.report.detail import detail_markdown
from evsmap.report.explore import study_markdown
from evsmap.report.int8 import int8_frame, int8_markdown, int8_records
from evsmap.report.realtime import realtime_markdown
from evsmap.report.run_data import load_run, read_records, read_run
from evsmap.report.tables import (
    STATUSES,
    extra_frame,
    proxy_accuracy_markdown,
    table_markdown,
)
from evsmap.runner.detail import is_detail
from evsmap.runner.records import CellRecord
from evsmap.tables.schema import PaperTable

PLOTS = {
    "networks.png": "speed against parameters and FLOPs (Tables I and II)",
    "mapping.png": "mapping rate and map size per sequence and system",
    "map_growth.png": "map size with the frames integrated, per sequence, system and reading",
    "qualitative.png": "segmentation overlays and top-down semantic maps",
}
_NO_DATA = {
    "networks.png": "no network of Table I or II has a measured speed and complexity",
    "mapping.png": "no mapping system was measured",
    "map_growth.png": "no mapping run recorded its growth",
    "qualitative.png": "the run stored no segmentation or map artifacts",
}


# ------------------------------------------------------------------------------- building
def build_report(run_dir: str | Path, *, study: Mapping[str, Any] | None | bool = True
                 ) -> list[Path]:
    """Write the report files of ``run_dir`` from its stored records; returns the files written
    (index.md last).

    ``study``: the design-space study linked from Table IV's section (``evsmap explore``'s
    :func:`~evsmap.explore.latest.latest_study` record); ``True``: the latest one, if any;
    ``None`` or ``False``: none (the gate's build, whose bytes must not depend on the cache).

    Raises:
        DataFormatError: ``run.json`` or a record is missing or corrupt (the message names the
            file).
    """
    run_dir = Path(run_dir)
    loaded = load_run(run_dir)
    run, records, tables, table_ids = loaded.run, loaded.records, loaded.tables, loaded.table_ids
    by_key, specs = loaded.by_key, loaded.specs
    extras, detail = loaded.extras, loaded.detail
    plotted = [r for r in records if not is_detail(r.row)]

    written: list[Path] = []
    frames = loaded.frames
    for tid in table_ids:
        table = tables[tid]
        frame = frames[tid]
        md = table_markdown(table, by_key, specs, frame=frame,
                            extras=extras if table.role == "mapping" else None)
        relative = relative_markdown(table, frame)
        if relative:
            md = md + "\n" + "\n".join(relative).rstrip() + "\n"
        if table.trained_beside:  # reproduce --train's networks, beside the table
            proxy = proxy_accuracy_markdown(extras)
            if proxy:
                md = md + "\n" + "\n".join(proxy).rstrip() + "\n"
        if table.role == "mapping":  # one network, Table IV's updates, 3D scores (ScanNet)
            section = detail_markdown(detail)
            if section:
                md = md + "\n" + "\n".join(section).rstrip() + "\n"
        if table.role == "mapping":  # where the claims hold: the latest `evsmap explore`
            linked = study_markdown(_study(study), run_dir)
            if linked:
                md = md + "\n" + "\n".join(linked).rstrip() + "\n"
        int8 = int8_markdown(records, tid)  # reproduce --precision int8, beside the table
        if table.role == "mapping":  # and its end-to-end rates, faithful path and variants
            int8 += realtime_markdown(records)
        if int8:
            md = md + "\n" + "\n".join(int8).rstrip() + "\n"
        written.append(_write(run_dir / f"{tid}.md", md))
        written.append(_write_csv(run_dir / f"{tid}.csv", frame))
    int8_path = run_dir / "int8.csv"
    if int8_records(records):
        written.append(_write_csv(int8_path, int8_frame(records)))
    else:
        int8_path.unlink(missing_ok=True)
    extra_path = run_dir / "extra.csv"
    if extras or detail:
        written.append(_write_csv(extra_path, extra_frame(extras + detail)))
    else:
        extra_path.unlink(missing_ok=True)

    labels = _map_labels(tables, records)
    drawn: dict[str, bool] = {}
    for name, draw in (
        ("networks.png", lambda p: plots.networks_plot(frames, p, records)),
        ("mapping.png", lambda p: plots.mapping_plot(plotted, p, tables)),
        ("map_growth.png", lambda p: plots.growth_plot(plotted, p)),
        ("qualitative.png", lambda p: plots.qualitative_plot(run_dir / "artifacts", p, labels)),
    ):
        path = run_dir / name
        drawn[name] = draw(path)
        if drawn[name]:
            written.append(path)
        else:
            path.unlink(missing_ok=True)  # a stale figure from an earlier build

    from evsmap.cache import cache_root, folder_size

    index = index_markdown(run, tables, table_ids, frames, extras, drawn,
                           has_extra_csv=bool(extras or detail), records=records, detail=detail,
                           sizes={"run": folder_size(run_dir)[1],
                                  "cache_root": str(cache_root()),
                                  "cache": folder_size(cache_root())[1]})
    written.append(_write(run_dir / "index.md", index))
    return written


def build_latex(run_dir: str | Path) -> list[Path]:
    """Write ``tableN.tex`` per table of ``run_dir`` (:func:`evsmap.report.latex.table_latex`)
    and ``tables.tex``, a document that inputs them; returns the files written (tables.tex
    last).

    Raises:
        DataFormatError: ``run.json`` or a record is missing or corrupt (names the file).
    """
    from evsmap.report.latex import document, report_latex

    run_dir = Path(run_dir)
    loaded = load_run(run_dir)
    texts = report_latex(loaded)
    written = [_write(run_dir / name, text) for name, text in texts.items()]
    title = f"evsmap run {loaded.run.get('run') or run_dir.name}"
    written.append(_write(run_dir / "tables.tex", document(list(texts), title)))
    return written


def _write(path: Path, text: str) -> Path:
    atomic_write_text(path, text)
    return path


def _write_csv(path: Path, frame: pd.DataFrame) -> Path:
    return _write(path, frame.to_csv(index=False))


def _study(study: Mapping[str, Any] | None | bool) -> Mapping[str, Any] | None:
    if study is True:
        from evsmap.explore.latest import latest_study

        return latest_study()
    return study or None


def _map_labels(tables: Mapping[str, PaperTable], records: list[CellRecord]) -> dict[str, str]:
    labels = {"octomap-cpp": "OctoMap (C++)"}
    for table in (t for t in tables.values() if t.role == "mapping"):
        labels.update({r.id: r.label for r in table.rows})
    for rec in records:
        if rec.key.startswith("extra/") and rec.label:
            labels.setdefault(rec.row, rec.label)
    return labels


# ------------------------------------------------------------------------------- index
def _lock_text(lock: Mapping) -> str:
    """``constraints.txt`` sha256 and whether the installed versions matched its pins."""
    head = f"`{lock.get('file', 'constraints.txt')}` sha256 {str(lock.get('sha256', ''))[:12]}"
    differs = lock.get("differs") or {}
    if not differs:
        return (f"{head}; the {lock.get('installed_pins', '?')} installed pinned packages match "
                f"the lock")
    listed = ", ".join(f"{_md(n)} {v[1]} (lock {v[0]})" for n, v in sorted(differs.items()))
    return f"{head}; **installed outside the lock**: {listed}"


def _md(text: Any) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def index_markdown(run: Mapping[str, Any], tables: Mapping[str, PaperTable],
                   table_ids: list[str], frames: Mapping[str, pd.DataFrame],
                   extras: list[CellRecord], drawn: Mapping[str, bool], *,
                   has_extra_csv: bool, sizes: Mapping[str, Any] | None = None,
                   records: list[CellRecord] | None = None,
                   detail: list[CellRecord] | None = None) -> str:
    """The run's ``index.md`` (``sizes``: bytes of the run folder and of the shared cache;
    ``records``: the run's records, for the timing precision)."""
    run_id = run.get("run") or "unknown"
    out = [f"# evsmap report - run {run_id}", ""]
    out += claims_markdown(frames, extras, detail or [])
    from evsmap.report.map_size import consistency_markdown
    from evsmap.runner.table4_reading import TABLE4_READING

    out += consistency_markdown(extras, TABLE4_READING)
    from evsmap.report.precision import precision_markdown

    out += precision_markdown(list(records or []), (run.get("context") or {}).get("timing"))
    from evsmap.report.accounting import accounting_markdown

    out += accounting_markdown(run.get("time_accounting"), list(records or []))
    out += _run_lines(run, tables, table_ids, frames, sizes)
    out += _environment_lines(run.get("environment") or {})
    out += _available_lines(run)
    out += _tables_lines(tables, table_ids, frames, extras, has_extra_csv)
    out += _figures_lines(drawn)
    out += _FILLING
    return "\n".join(out).rstrip() + "\n"


def _run_lines(run: Mapping[str, Any], tables: Mapping[str, PaperTable], table_ids: list[str],
               frames: Mapping[str, pd.DataFrame], sizes: Mapping[str, Any] | None) -> list[str]:
    """The run's facts: when it ran, whether quick, its timing, its folder, its inputs."""
    finished = run.get("finished") or "not finished (interrupted, or still running)"
    out = [f"- Started: {run.get('started') or 'unknown'}", f"- Finished: {finished}"]
    if run.get("quick"):
        out.append("- Quick run (`--quick`): smaller inputs and fewer frames than the paper's "
                   "settings")
    out += _timing_lines(tables, table_ids, frames)
    if sizes:
        out.append(f"- Run folder: {sizes['run'] / 1e6:.1f} MB (records, tables, plots, small "
                   f"artifacts); ONNX exports, segmentations and rendered sequences live in the "
                   f"cache shared across runs, `{sizes['cache_root']}` "
                   f"({sizes['cache'] / 1e6:.1f} MB, `evsmap cache info`)")
    out.append(f"- Data root: `{run['data_root']}`" if run.get("data_root")
               else "- Data root: none")
    out.append(f"- Weights folder: `{run['weights_dir']}`" if run.get("weights_dir")
               else "- Weights folder: none (networks run with untrained weights where a cell "
                    "allows it; accuracy cells need trained weights)")
    out.append("")
    return out


def _timing_lines(tables: Mapping[str, PaperTable], table_ids: list[str],
                  frames: Mapping[str, pd.DataFrame]) -> list[str]:
    """The timed cells flagged as taken on a busy machine, or that none was."""
    flagged = [(tid, r) for tid in table_ids for r in frames[tid].to_dict("records")
               if isinstance(r.get("timing_flag"), str) and r["timing_flag"]]
    timed = sum(int(((frames[tid]["status"] == "ok")
                     & frames[tid]["unit"].isin(["FPS", "Hz"])).sum()) for tid in table_ids)
    if flagged:
        cells = ", ".join(f"{tables[tid].number}: {r['label']} / {r['header']}"
                          for tid, r in flagged[:6]) + (" ..." if len(flagged) > 6 else "")
        return [f"- **Timing: {len(flagged)} timed cell(s) flagged** (marked `~`: the "
                f"machine was busy, or an older run's median was not steady) - Table {cells}. "
                f"Rerun them on an idle machine, or with `--strict-timing`."]
    if timed:
        return [f"- Timing: all {timed} timed cells (speeds, mapping rates) were taken with no "
                f"contention seen by the calibration (the speeds' precision: \"Timing "
                f"precision\" above)"]
    return []


_ENVIRONMENT_KEYS = (("cpu", "CPU"), ("instruction_set", "instruction set"),
                     ("cpu_flags", "vector flags"), ("cpus", "CPU cores"),
                     ("threads", "threads"), ("python", "Python"), ("host", "host"),
                     ("git_commit", "git commit"))
"""The environment's facts shown first in the index (key, name), then the libraries' versions,
the lock, and any other key as it is."""


def _environment_lines(env: Mapping[str, Any]) -> list[str]:
    """The "Environment" section (nothing without an environment)."""
    if not env:
        return []
    out = ["## Environment", "", "| | |", "|---|---|"]
    for key, name in _ENVIRONMENT_KEYS:
        value = env.get(key)
        if isinstance(value, list):
            value = ", ".join(map(str, value))
        if value not in (None, ""):
            out.append(f"| {name} | {_md(value)} |")
    versions = env.get("versions") or {}
    if isinstance(versions, Mapping):
        for lib, version in versions.items():
            out.append(f"| {_md(lib)} | {_md(version if version else 'not installed')} |")
    lock = env.get("lock")
    if isinstance(lock, Mapping):
        out.append(f"| lock | {_lock_text(lock)} |")
    shown = {key for key, _ in _ENVIRONMENT_KEYS} | {"versions", "lock"}
    for key, value in env.items():
        if key not in shown:
            out.append(f"| {_md(key)} | {_md(value)} |")
    out.append("")
    return out


def _available_lines(run: Mapping[str, Any]) -> list[str]:
    """The "Available" section: what the run found, and its mapping sequences."""
    out = ["## Available", ""]
    available = run.get("available") or []
    out += ([f"- `{a}`" for a in available] if available
            else ["Nothing beyond evsmap itself (no dataset, no trained weights, no special "
                  "hardware)."])
    out.append("")
    sequences = run.get("sequences") or {}
    if sequences:
        out += ["Mapping sequences:", "", "| sequence | frames | size | scene | labels |",
                "|---|---:|---|---|---|"]
        for name, s in sequences.items():
            s = s if isinstance(s, Mapping) else {}
            size = (f"{s['width']}x{s['height']}" if s.get("width") and s.get("height")
                    else "-")
            out.append(f"| {_md(name)} | {_md(s.get('frames', '-'))} | {size} | "
                       f"{_md(s.get('scene') or '-')} | {_md(s.get('labels') or '-')} |")
        out.append("")
    return out


def _tables_lines(tables: Mapping[str, PaperTable], table_ids: list[str],
                  frames: Mapping[str, pd.DataFrame], extras: list[CellRecord],
                  has_extra_csv: bool) -> list[str]:
    """The "Tables" section: each table's cells by status, and the measurements beyond."""
    out = ["## Tables", "",
           "| table | " + " | ".join(STATUSES) + " | files |",
           "|---|" + "---:|" * len(STATUSES) + "---|"]
    for tid in table_ids:
        counts = frames[tid]["status"].value_counts()
        table = tables[tid]
        cells = " | ".join(str(int(counts.get(s, 0))) for s in STATUSES)
        out.append(f"| Table {table.number}: {_md(table.title)} | {cells} | "
                   f"[{tid}.md]({tid}.md), [{tid}.csv]({tid}.csv) |")
    out += ["", "Cells: `ok` measured; `n/a` cannot be measured here (the table's notes say what "
            "is missing); `error` the run failed; `not run` no record (the run was interrupted "
            "or did not include the cell); `no value` a record without that value; `paper "
            "only` a row evsmap does not implement.", ""]
    if extras:
        n = {s: sum(1 for r in extras if r.status == s) for s in ("ok", "na", "error")}
        out += [f"Measurements beyond the paper: {n['ok']} ok, {n['na']} n/a, {n['error']} "
                "error, in [table4.md](table4.md) (\"Measured beyond the paper\")"
                + (" and [extra.csv](extra.csv)." if has_extra_csv else "."), ""]
    return out


def _figures_lines(drawn: Mapping[str, bool]) -> list[str]:
    """The "Figures" section: a link to each figure drawn (why not, for the others), then the
    figures themselves."""
    out = ["## Figures", ""]
    for name, what in PLOTS.items():
        if drawn.get(name):
            out.append(f"- [{name}]({name}): {what}")
        else:
            out.append(f"- {name}: skipped, {_NO_DATA[name]}")
    out.append("")
    for name in PLOTS:
        if drawn.get(name):
            out += [f"![{PLOTS[name]}]({name})", ""]
    return out


_FILLING = ["## Filling the n/a cells", "",
            "An `n/a` cell names what it needs. Datasets: prepare them with "
            "`evsmap datasets prepare` under the data root (or give `--data-root DIR`). "
            "Trained weights: give `--weights-dir DIR` with one file per network and dataset "
            "named `<segmenter>@<dataset>.pt` (the segmenter spec as the note prints it, e.g. "
            "`feagnet-v2@nyuv2.pt`). The starred Jetson cells (TensorRT speeds) need a Jetson "
            "AGX Xavier with TensorRT; they stay n/a on any other machine. Then run "
            "`evsmap reproduce` again, and `evsmap report DIR` to rebuild these files from the "
            "stored records.", ""]
"""The index's last section: how to fill the n/a cells."""


__all__ = ["PLOTS", "build_latex", "build_report", "index_markdown", "read_records", "read_run"]
