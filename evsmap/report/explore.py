"""A study's report: ``trials.csv`` (every trial), the Pareto fronts as plots (map size vs 3D
mIoU, update-rate ratio vs 3D mIoU; the paper's default point and the baseline's marked) and
``index.md`` with the plain answer (:func:`evsmap.explore.results.answer`)."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from evsmap.explore.results import (
    FRONTS,
    MIOU_LOSS_POINTS,
    PAPER_SIZE_RATIO,
    Answer,
    answer,
    complete,
    pareto_front,
)
from evsmap.explore.space import Space
from evsmap.report.figure_base import empty_panel, new_figure, save_figure

CSV_FILE = "trials.csv"
INDEX_FILE = "index.md"
PLOTS = {"size": "front-size-miou.png", "rate": "front-rate-miou.png"}


def write_csv(rows: list[dict[str, Any]], path: Path) -> None:
    """Every trial, one row each (the columns: the union of the rows' keys, in first-seen
    order)."""
    from evsmap.fileio import atomic_write_text

    columns: list[str] = []
    for row in rows:
        columns += [k for k in row if k not in columns]
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: "" if row.get(k) is None else row[k] for k in columns})
    atomic_write_text(path, buffer.getvalue())


def _mb(value: float | None) -> str:
    return "n/a" if value is None else f"{value / 1e6:.2f}"


def _pct(value: float | None) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{100 * value:.1f}"


def _params(row: dict[str, Any], space: Space) -> str:
    return ", ".join(f"{p.name}={_num(row.get('param:' + p.name))}" for p in space.parameters)


def _num(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _axis(name: str) -> tuple[str, float]:
    """An axis label and the factor its values are shown with."""
    return {"map_size": ("map size, Table IV's reading (MB)", 1e-6),
            "scene_miou": ("3D mIoU over the observed scene (%)", 100.0),
            "rate_ratio": ("update rate / OctoMap C++'s (same process)", 1.0)}[name]


def plot_front(rows: list[dict[str, Any]], which: str, path: Path, *, space: Space,
               title: str) -> None:
    """All complete trials, the Pareto front of ``which`` (:data:`FRONTS`), the paper's default
    trial and the baseline at the default's shared settings."""
    x, y, x_lower, y_lower = FRONTS[which]
    (xl, xf), (yl, yf) = _axis(x), _axis(y)
    fig = new_figure(6.4, 4.4, layout="constrained")
    ax = fig.add_subplot()
    done = [r for r in complete(rows) if r.get(x) is not None and r.get(y) is not None]
    if not done:
        empty_panel(ax, "no complete trial yet")
        save_figure(fig, path)
        return
    ax.scatter([r[x] * xf for r in done], [r[y] * yf for r in done], s=16, color="0.6",
               label=f"trials ({len(done)})", zorder=2)
    paired = sorted({(r[f"baseline_{x}"], r[f"baseline_{y}"]) for r in done
                     if r.get(f"baseline_{x}") is not None
                     and r.get(f"baseline_{y}") is not None})
    if paired:
        ax.scatter([p[0] * xf for p in paired], [p[1] * yf for p in paired], s=18, marker="x",
                   color="tab:green", alpha=0.6, zorder=2,
                   label=f"{space.baseline} at each trial's shared settings ({len(paired)})")
    front = pareto_front(done, x, y, x_lower=x_lower, y_lower=y_lower)
    ax.plot([r[x] * xf for r in front], [r[y] * yf for r in front], "-o", color="tab:blue",
            ms=5, label=f"Pareto front ({len(front)})", zorder=3)
    default = next((r for r in done if r.get("role")), None)
    if default is not None:
        ax.scatter([default[x] * xf], [default[y] * yf], marker="*", s=180, color="tab:red",
                   label=f"{space.updater} at the paper's defaults", zorder=4)
        bx, by = default.get(f"baseline_{x}"), default.get(f"baseline_{y}")
        if bx is not None and by is not None:
            ax.scatter([bx * xf], [by * yf], marker="D", s=70, color="tab:green",
                       label=f"{space.baseline} (baseline) at the same settings", zorder=4)
    if x == "map_size":
        from matplotlib.ticker import FormatStrFormatter, NullFormatter

        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel(xl + (" - lower is better" if x_lower else " - higher is better"))
    ax.set_ylabel(yl + " - higher is better")
    ax.set_title(title, fontsize=9)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    save_figure(fig, path)


def answer_line(found: Answer, space: Space) -> str:
    """The answer in one sentence (the study's index and the reproduce report's link)."""
    if not found.paired:
        return f"{found.trials} trials; no baseline paired, no size ratio measured"
    if found.best is None:
        best = found.best_any
        ratio = f"; the largest size ratio of any trial is {best['size_ratio']:.2f}x" if best \
            else ""
        return (f"over {found.trials} trials, {space.updater}'s map is never smaller than "
                f"{space.baseline}'s at no more than {MIOU_LOSS_POINTS:g} point of 3D mIoU "
                f"lost{ratio}; the paper's 'up to {PAPER_SIZE_RATIO}x' is not reached")
    reach = "reached" if found.reaches_paper else "not reached"
    return (f"over {found.trials} trials, {len(found.within)} give a map smaller than "
            f"{space.baseline}'s at no more than {MIOU_LOSS_POINTS:g} point of 3D mIoU lost; "
            f"the best is {found.best['size_ratio']:.2f}x; the paper's 'up to "
            f"{PAPER_SIZE_RATIO}x' is {reach}")


def _front_table(rows: list[dict[str, Any]], which: str, space: Space) -> list[str]:
    x, y, x_lower, y_lower = FRONTS[which]
    front = pareto_front(complete(rows), x, y, x_lower=x_lower, y_lower=y_lower)
    lines = ["| trial | map size (MB) | scene mIoU (%) | kept leaves' mIoU (%) | recall (%) "
             "| rate ratio | size ratio | mIoU loss (pt) | parameters |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in front:
        lines.append(f"| {r['number']} | {_mb(r.get('map_size'))} | {_pct(r.get('scene_miou'))} "
                     f"| {_pct(r.get('map_miou'))} | {_pct(r.get('recall'))} "
                     f"| {_ratio(r.get('rate_ratio'))} "
                     f"| {_ratio(r.get('size_ratio'))} | {_signed(r.get('miou_loss'))} "
                     f"| {_params(r, space)} |")
    return lines


def _ratio(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.2f}x"


def _signed(value: float | None) -> str:
    return "n/a" if value is None else f"{value:+.2f}"


def _space_table(space: Space) -> list[str]:
    lines = ["| parameter | applies to | range | paper's default | source |",
             "|---|---|---|---:|---|"]
    for p in space.parameters:
        target = "every map (shared)" if p.target == "shared" else space.updater
        lines.append(f"| `{p.name}` | {target} | {p.describe()} | {_num(p.default)} "
                     f"| {p.source} |")
    return lines


def _answer_section(found: Answer, space: Space) -> list[str]:
    lines = ["## The answer", "", answer_line(found, space) + ".", ""]
    d = found.default
    if d is not None:
        lines += [f"At the paper's defaults (trial {d['number']}): {space.updater}'s map "
                  f"{_mb(d.get('map_size'))} MB against {space.baseline}'s "
                  f"{_mb(d.get('baseline_map_size'))} MB (size ratio "
                  f"{_ratio(d.get('size_ratio'))}), scene mIoU {_pct(d.get('scene_miou'))} % "
                  f"against {_pct(d.get('baseline_scene_miou'))} %, update rate "
                  f"{_ratio(d.get('rate_ratio'))} OctoMap C++'s.", ""]
    if found.best is not None:
        b = found.best
        lines += [f"Best smaller map within {MIOU_LOSS_POINTS:g} point: trial {b['number']}, "
                  f"size ratio **{b['size_ratio']:.2f}x** ({_mb(b.get('map_size'))} MB against "
                  f"{_mb(b.get('baseline_map_size'))} MB), scene mIoU "
                  f"{_pct(b.get('scene_miou'))} % (loss {_signed(b.get('miou_loss'))} pt), "
                  f"rate ratio {_ratio(b.get('rate_ratio'))}; parameters: {_params(b, space)}.", "",
                  "Where it holds (the range of each parameter over those trials):", "",
                  "| parameter | min | max |", "|---|---:|---:|"]
        lines += [f"| `{k}` | {_num(lo)} | {_num(hi)} |" for k, (lo, hi) in
                  found.region.items()]
        lines.append("")
    elif found.best_any is not None:
        b = found.best_any
        lines += [f"Largest size ratio of any trial: trial {b['number']}, "
                  f"{b['size_ratio']:.2f}x at a 3D mIoU loss of {_signed(b.get('miou_loss'))} "
                  f"pt; parameters: {_params(b, space)}.", ""]
    return lines


def _point_name(r: Mapping[str, Any]) -> str:
    return f"trial {r['trial']} ({r['point']})"


def _labels_name(r: Mapping[str, Any]) -> str:
    return f"{r['source']} (the study's)" if r.get("study_labels") else str(r["source"])


def _yes(value: Any) -> str:
    return "yes" if value else "no"


def _sensitivity_table(records: list[dict[str, Any]], space: Space) -> list[str]:
    lines = [f"| key point | labels | size ratio | {space.updater} (MB) | {space.baseline} (MB) "
             f"| scene mIoU (%) | {space.baseline}'s (%) | mIoU loss (pt) | smaller at <= "
             f"{MIOU_LOSS_POINTS:g} pt lost |",
             "|---|---|---:|---:|---:|---:|---:|---:|---|"]
    for r in records:
        lines.append(f"| {_point_name(r)} | {_labels_name(r)} | {_ratio(r.get('size_ratio'))} "
                     f"| {_mb(r.get('map_size'))} | {_mb(r.get('baseline_map_size'))} "
                     f"| {_pct(r.get('scene_miou'))} | {_pct(r.get('baseline_scene_miou'))} "
                     f"| {_signed(r.get('miou_loss'))} | {_yes(r.get('meets'))} |")
    return lines


CLAIMS = {"smaller": ("the map is smaller than {b}'s", "the map is not smaller than {b}'s"),
          "within": (f"it loses no more than {MIOU_LOSS_POINTS:g} pt of scene mIoU",
                     f"it loses more than {MIOU_LOSS_POINTS:g} pt of scene mIoU")}
"""Each conclusion a key point gives, when true and when false."""


def _by_point(records: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    points: dict[str, list[dict[str, Any]]] = {}
    for r in records:
        points.setdefault(_point_name(r), []).append(r)
    return points


def sensitivity_verdict(records: list[dict[str, Any]], space: Space) -> str:
    """One sentence: the conclusions that hold under every label source, and those that
    depend on the labels (with the sources on each side)."""
    holds, depends = [], []
    for point, rows in _by_point(records).items():
        for claim, (yes, no) in CLAIMS.items():
            values = [bool(r.get(claim)) for r in rows]
            if all(values) or not any(values):
                text = yes if all(values) else no
                holds.append(f"at {point} {text.format(b=space.baseline)}")
                continue
            on = ", ".join(_labels_name(r) for r in rows if r.get(claim))
            off = ", ".join(_labels_name(r) for r in rows if not r.get(claim))
            depends.append(f"at {point} whether {yes.format(b=space.baseline)} (yes with "
                           f"{on}; no with {off})")
    said = "Under every label source, " + "; ".join(holds) if holds else \
        "No conclusion holds under every label source"
    if depends:
        said += "; it depends on the labels " + "; ".join(depends)
    return said + "."


def _sizes_line(records: list[dict[str, Any]]) -> str:
    """Whether the map sizes moved with the labels (checked, not assumed), and by how much."""
    moved = []
    for point, rows in _by_point(records).items():
        if len({(r.get("map_size"), r.get("baseline_map_size")) for r in rows}) > 1:
            ratios = [r["size_ratio"] for r in rows if r.get("size_ratio")]
            spread = 100.0 * (max(ratios) - min(ratios)) / min(ratios)
            moved.append(f"{point} (its size ratio by {spread:.3g} %)")
    if not moved:
        return ("The map sizes are the same under every labelling (the trees prune on "
                "occupancy): the size ratios do not move with the labels, the mIoU does.")
    return (f"The map sizes move with the labels at {', '.join(moved)}: a map's pruning or "
            f"merging reads the classes there.")


def sensitivity_section(records: list[dict[str, Any]], space: Space) -> list[str]:
    """"How the answer moves with the labels": a table per key point and label source, the
    sentence saying which conclusions hold under every source, and which labels the study's
    own trials used."""
    if not records:
        return []
    own = next((r for r in records if r.get("study_labels")), None)
    used = "" if own is None else (
        f"The study's own trials were labelled by **{own['source']}** (segmenter "
        f"`{own.get('segmenter')}`"
        + (f", profile `{own['profile']}`" if own.get("profile") else "")
        + (f", weights `{own['weights']}`" if own.get("weights") else "")
        + "); its row repeats the trial's own figures. ")
    return ["## How the answer moves with the labels", "",
            f"{used}Each other row maps the key point's settings and its paired {space.baseline} "
            f"baseline again with that source's labels of the same frames (the oracle's "
            f"profiles: docs/oracle.md). The study is not run again: a point that is not the "
            f"best under the study's labels is not looked for under the others.", "",
            *_sensitivity_table(records, space), "",
            sensitivity_verdict(records, space), "", _sizes_line(records), ""]


def study_markdown(study: Mapping[str, Any] | None, run_dir: Path) -> list[str]:
    """Table IV's link to a design-space study (``evsmap explore``'s latest record): where it
    is, relative to the run folder, and its answer; nothing without one."""
    if not study:
        return []
    import os
    from datetime import UTC, datetime

    index = str(study["index"])
    try:
        link = os.path.relpath(index, run_dir)
    except ValueError:  # another drive
        link = index
    when = datetime.fromtimestamp(float(study.get("written", 0)), UTC).strftime("%Y-%m-%d %H:%M")
    return ["## Where the map-size claim holds: the latest design-space study", "",
            f"`evsmap explore` ({when} UTC, [{link}]({link})): {study.get('summary', '')}. "
            f"Each of its trials maps one sequence at other settings of the updater's options "
            f"and of the shared front end, beside the baseline's map at the same settings "
            f"(docs/explore.md).", ""]


def write_report(study_dir: Path, rows: list[dict[str, Any]], space: Space, *,
                 header: dict[str, str],
                 sensitivity: list[dict[str, Any]] | None = None) -> tuple[Path, str]:
    """``trials.csv``, the two front plots and ``index.md`` in ``study_dir``; the index's path
    and the one-line answer. ``header``: the study's facts (label -> text) printed first;
    ``sensitivity``: the key points' records under each label source
    (:func:`evsmap.explore.sensitivity.run_sensitivity`), a section after the answer."""
    from evsmap.fileio import atomic_write_text

    study_dir.mkdir(parents=True, exist_ok=True)
    write_csv(rows, study_dir / CSV_FILE)
    found = answer(rows)
    title = f"{space.updater} vs {space.baseline}, {found.trials} trials"
    for which, name in PLOTS.items():
        plot_front(rows, which, study_dir / name, space=space, title=title)
    states: dict[str, int] = {}
    for r in rows:
        states[r["state"]] = states.get(r["state"], 0) + 1
    lines = [f"# Design-space study: {space.updater}", ""]
    lines += [f"- {label}: {text}" for label, text in header.items()]
    walls = [r["wall_s"] for r in complete(rows) if r.get("wall_s") is not None]
    lines += [f"- trials: {', '.join(f'{n} {s.lower()}' for s, n in sorted(states.items()))}"
              + (f"; {sum(walls) / 60:.1f} min of measuring in all (median trial "
                 f"{sorted(walls)[len(walls) // 2]:.0f} s)" if walls else ""),
              f"- every trial: [{CSV_FILE}]({CSV_FILE})", ""]
    lines += _answer_section(found, space)
    lines += sensitivity_section(sensitivity or [], space)
    lines += ["## Pareto fronts", "",
              "3D mIoU here is the scene mIoU: every observed ground-truth voxel scored by the map "
              "(one the map dropped is a miss); the mIoU of the leaves the map kept and the "
              "recall are beside it.", "",
              f"![map size vs 3D mIoU]({PLOTS['size']})", "",
              *_front_table(rows, "size", space), "",
              f"![update-rate ratio vs 3D mIoU]({PLOTS['rate']})", "",
              *_front_table(rows, "rate", space), "",
              "## The space", "", *_space_table(space), "",
              "How each quantity is measured: docs/explore.md.", ""]
    index = study_dir / INDEX_FILE
    atomic_write_text(index, "\n".join(lines))
    return index, answer_line(found, space)
