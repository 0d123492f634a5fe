"""Mapping runs that are the same run under two rows, mapped once.

Without trained weights every semantic row maps with the oracle's labels, so the
semantic-detail section's rows (:mod:`evsmap.runner.detail`: one network feeding every update)
can be Table IV's own runs again: ``detail-evsmap`` is ``evsmap`` (the same updater, network,
labels, frames and voxel size) and ``detail-orgbmap`` is ``orgbmap``. Such a run is mapped once
and its record copied to the other row (its key, row and label, and a note naming the run it
is), the map the report's views show copied beside it. The copy is the same measurement, not a
second one: its map is byte for byte the first's (the map is deterministic), and its timing is
the first's, which is why the note says so.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any

from evsmap.runner.mapping_plan import MappingRun
from evsmap.runner.records import CellRecord

SAME_RUN_NOTE = ("mapped once with {key}: the same updater, network, labels, frames and voxel "
                 "size, so the map and its timing are that run's")


def run_identity(run: MappingRun) -> tuple[Any, ...]:
    """What a mapping run's map and timing depend on (not its row, label or views)."""
    labels = None if run.labels is None else json.dumps(run.labels.as_dict(), sort_keys=True)
    return (run.segmenter, run.updater, run.sequence, run.resolution, run.own_labels, labels)


def same_runs(runs: list[MappingRun]) -> tuple[list[MappingRun], dict[str, list[MappingRun]]]:
    """``(to_map, copies)``: the runs to map (one per identity, a run that saves the report's
    views where any of its group does) and, by the key of each, the runs it stands for."""
    groups: dict[tuple[Any, ...], list[MappingRun]] = {}
    for run in runs:
        groups.setdefault(run_identity(run), []).append(run)
    to_map: list[MappingRun] = []
    copies: dict[str, list[MappingRun]] = {}
    for group in groups.values():
        first = next((r for r in group if r.views), group[0])
        to_map.append(first)
        if len(group) > 1:
            copies[first.key] = [r for r in group if r is not first]
    order = {r.key: i for i, r in enumerate(runs)}
    return sorted(to_map, key=lambda r: order[r.key]), copies


def copied_record(record: CellRecord, first: MappingRun, run: MappingRun,
                  out: str | Path) -> CellRecord:
    """``record`` (``first``'s) as ``run``'s: its key, row, label and inputs, a note naming the
    run it is, no time of its own, and the map the report's views show copied beside it."""
    fields = run.base_fields()
    copy = replace(record, key=fields["key"], row=fields["row"], label=fields["label"],
                   inputs=fields["inputs"], notes=[*record.notes,
                                                   SAME_RUN_NOTE.format(key=record.key)],
                   details={**record.details, "same_run_as": record.key}, seconds=0.0,
                   around={"wall_s": 0.0})
    if run.views and record.status == "ok":
        artifacts = Path(out) / "artifacts"
        source = artifacts / f"map-{first.row}-{first.sequence}.npz"
        if source.exists():
            shutil.copyfile(source, artifacts / f"map-{run.row}-{run.sequence}.npz")
    return copy
