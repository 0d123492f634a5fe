"""Table IV's cells read from the mapping runs (:func:`table4_record`), so that each map is built
once: the Map Size reading (:data:`TABLE4_READING` of :data:`READINGS`) and the Runtime, the
segmentation + update rate on the one sequence every row maps (:func:`runtime_sequence`)."""

from __future__ import annotations

from evsmap.runner.cell_base import base_fields, column_quantities, now
from evsmap.runner.context import RunContext
from evsmap.runner.mapping_plan import mapping_key
from evsmap.runner.records import CellRecord
from evsmap.tables.schema import CellSpec, mapping_table

READINGS = {"saved file": "map_bytes", "octomap_full message": "map_bytes_message",
            "colour-only file": "map_bytes_colour",
            "C++ memory (model)": "octomap_memory_bytes"}
"""The four readings of a map's size every mapping run records (reading -> its value): the file
the system itself saves, the full map as its ROS node sends it (the saved file's bytes except
SSMI's, whose message carries the semantics), the colour-only ``ColorOcTree`` every system can
write, OctoMap's memory model over the system's C++ node (:mod:`evsmap.report.map_size` compares
them)."""


TABLE4_READING = "C++ memory (model)"
"""The reading Table IV's Map Size cells take: of the three, the one whose ratios come closest to
the paper's own Seq.1 rows on the TUM frames (docs/mapping.md, "Which Map Size")."""


def runtime_sequence(sequences: list[str], runs: dict[str, CellRecord],
                     voxel: float) -> tuple[str, bool]:
    """The one sequence Table IV's Runtime column is measured on for every row: the first of
    the column's ``sequences`` that every implemented Table IV system mapped here, else the
    synthetic one (which every system can map, with the oracle's labels). Returns it and
    whether it is that fallback."""
    rows = [r.id for r in mapping_table().rows
            if r.implemented and r.updater is not None]
    for seq in sequences:
        found = [runs.get(mapping_key(row, seq, voxel)) for row in rows]
        if all(r is not None and r.status == "ok" for r in found):
            return seq, False
    return "synthetic", True


def table4_record(spec: CellSpec, runs: dict[str, CellRecord], ctx: RunContext) -> CellRecord:
    """A Table IV cell from the mapping runs: the map size on its sequence, or the Runtime, the
    segmentation + update rate (``segment_update_hz``: not the end-to-end rate, the loop's
    wall rate ``wall_hz``), on the one sequence every row's rate comes from
    (:func:`runtime_sequence`), so the column compares systems on the same frames."""
    base = base_fields(spec)
    voxel = spec.resolution or ctx.resolution

    def run_of(seq: str) -> CellRecord | None:
        return runs.get(mapping_key(spec.row, seq, voxel))

    quantities = column_quantities(spec)
    values, notes, details = {}, [], {}
    for col, q in quantities.items():
        if q == "map_size":
            source = run_of(spec.datasets[0])
            if source is None or source.status != "ok":
                return _from_failed(spec, source)
            value = READINGS[TABLE4_READING]
            if source.values.get(value) is None:
                return CellRecord(**base, status="na", reason=f"n/a - {spec.row} has no "
                                  f"{TABLE4_READING}", started=now())
            values[col] = source.values[value]
            notes += [f"Map Size read as the {TABLE4_READING} (the saved file: "
                      f"{source.values['map_bytes'] / 1e6:.3f} MB)"] + source.notes
            details[col] = {"source": source.key}
        else:  # runtime_hz
            seq, fallback = runtime_sequence(list(spec.datasets), runs, voxel)
            source = run_of(seq)
            if source is None or source.status != "ok":
                return _from_failed(spec, source)
            values[col] = source.values["segment_update_hz"]
            base["inputs"]["sequence"] = seq
            notes.append(f"segmentation + update rate measured on {seq} for every row"
                         + (" (no sequence of the paper's could be mapped by every system "
                            "here)" if fallback else "") + "; " + "; ".join(source.notes))
            details[col] = {"source": source.key}
            for name in ("timing_flag", "calibration_gmacs", "rel_ci"):
                if (source.details or {}).get(name):
                    details[name] = source.details[name]
    return CellRecord(**base, status="ok", values=values, notes=notes, details=details,
                      started=now())


def _from_failed(spec: CellSpec, source: CellRecord | None) -> CellRecord:
    if source is None:
        return CellRecord(**base_fields(spec), status="error", error="its mapping run did not run",
                          started=now())
    return CellRecord(**base_fields(spec), status=source.status, needs=source.needs,
                      reason=source.reason, error=source.error, started=now())
