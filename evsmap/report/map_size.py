"""Which "Map Size" did the paper measure, and does its size claim hold under each reading?

Table IV prints one "Map Size (MB)" per system and sequence without saying what was measured. A
map's size can be read four ways, all measured on every mapping run (:data:`READINGS`): the file
the system itself saves, the map as its ROS node sends it (``octomap_full``: the saved file's bytes
except SSMI's, which carries the semantics), the colour-only ``ColorOcTree`` every system can
write, and OctoMap's memory model over the system's C++ node. The paper's own rows constrain the
reading: on Seq.1 (TUM) TESAMap / ORGBMap is 1.53, MESAMap / TESAMap 1.08 and EVSMap / TFEAGMap
0.93 (:data:`PAIRS`). :func:`consistency_markdown` sets each reading's ratios beside the paper's,
on every sequence and voxel size mapped, and names the reading that comes closest (the mean of
``|log(measured / paper)|``); :func:`verdict_rows` checks "EVSMap's map is smaller", the paper's
"up to 2.6x", under each reading.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

from evsmap.runner.records import CellRecord
from evsmap.runner.table4_reading import READINGS

PAIRS = {"TESAMap / ORGBMap": ("tesamap", "orgbmap"),
         "MESAMap / TESAMap": ("mesamap", "tesamap"),
         "EVSMap / TFEAGMap": ("evsmap", "tfeagmap")}
"""The row ratios the paper's Seq.1 column fixes (numerator row, denominator row)."""

CLAIMED_SHRINK = 2.6
"""The paper: EVSMap's map "up to 2.6x" smaller than the traditional update's."""


def paper_ratios(seq_column: str = "size_seq1") -> dict[str, float]:
    """The paper's :data:`PAIRS` ratios from its printed Table IV cells."""
    from evsmap.tables.schema import mapping_table

    table = mapping_table()

    def size(row: str) -> float:
        value = table.cell(row, seq_column).value
        assert value is not None, f"Table IV prints a size for {row}"  # the pairs' rows do
        return value

    return {name: size(a) / size(b) for name, (a, b) in PAIRS.items()}


def _runs(extras: Iterable[CellRecord]) -> dict[tuple[str, float], dict[str, CellRecord]]:
    """(sequence, voxel size) -> row -> its ok mapping run."""
    out: dict[tuple[str, float], dict[str, CellRecord]] = {}
    for r in extras:
        if r.status == "ok" and r.key.startswith("extra/mapping/"):
            where = (str(r.inputs.get("sequence")), float(r.inputs.get("resolution") or 0.0))
            out.setdefault(where, {})[r.row] = r
    return out


def _ratio(rows: Mapping[str, CellRecord], a: str, b: str, value: str) -> float | None:
    if a not in rows or b not in rows:
        return None
    x, y = rows[a].values.get(value), rows[b].values.get(value)
    return x / y if x and y else None


def reading_errors(rows: Mapping[str, CellRecord],
                   paper: Mapping[str, float]) -> dict[str, tuple[dict[str, float | None],
                                                                  float | None]]:
    """Per reading: the measured :data:`PAIRS` ratios and their mean ``|log(measured /
    paper)|`` (None unless every pair was measured)."""
    out = {}
    for reading, value in READINGS.items():
        ratios = {name: _ratio(rows, a, b, value) for name, (a, b) in PAIRS.items()}
        done = [abs(math.log(r / paper[n])) for n, r in ratios.items() if r]
        out[reading] = (ratios, sum(done) / len(done) if len(done) == len(PAIRS) else None)
    return out


def consistency_markdown(extras: Iterable[CellRecord], table4_reading: str) -> list[str]:
    """The "which Map Size" table: each reading's ratios beside the paper's Seq.1 ones, per
    sequence and voxel size, the closest reading marked."""
    runs, paper = _runs(extras), paper_ratios()
    blocks = [(where, rows) for where, rows in sorted(runs.items())
              if all(a in rows and b in rows for a, b in PAIRS.values())]
    if not blocks:
        return []
    out = ["## Which \"Map Size\" did the paper measure?", "",
           "The paper does not say what its Map Size is. Each reading below is measured on every "
           "mapping run; the paper's own Seq.1 (TUM) rows fix three ratios. The reading whose "
           "ratios come closest (mean |log(measured / paper)|, **bold**) is the one the paper's "
           f"rows support here. Table IV's Map Size uses the {table4_reading} "
           "(see docs/mapping.md, \"Which Map Size\"); the others are in the extra section. "
           "The paper's TESAMap/TFEAGMap and MESAMap/EVSMap pairs differ by the network only; "
           "where they are mapped with the same labels (the oracle's) their ratios coincide.",
           "", "| sequence | voxel | reading | " + " | ".join(PAIRS) + " | mean abs log |",
           "|---|---:|---|" + "---:|" * len(PAIRS) + "---:|",
           "| paper, Seq.1 | ? | ? | " + " | ".join(f"{paper[n]:.2f}" for n in PAIRS)
           + " | - |"]
    for (seq, voxel), rows in blocks:
        errors = reading_errors(rows, paper)
        scored = [(e, r) for r, (_, e) in errors.items() if e is not None]
        best = min(scored)[1] if scored else None
        for reading, (ratios, error) in errors.items():
            cells = " | ".join("-" if v is None else f"{v:.2f}" for v in ratios.values())
            name = f"**{reading}**" if reading == best else reading
            out.append(f"| {seq} | {voxel * 100:g} cm | {name} | {cells} | "
                       + ("-" if error is None else f"{error:.3f}") + " |")
    out.append("")
    return out


def verdict_rows(extras: Iterable[CellRecord],
                 readings: Iterable[str] | None = None) -> list[str]:
    """Claim-table rows: EVSMap / TFEAGMap and MESAMap / TESAMap under each reading (or each of
    ``readings``), on each sequence and voxel size where both were mapped, against the paper's
    "up to 2.6x"."""
    chosen = READINGS if readings is None else {r: READINGS[r] for r in readings}
    out = []
    for (seq, voxel), rows in sorted(_runs(extras).items()):
        for pair in ("EVSMap / TFEAGMap", "MESAMap / TESAMap"):
            a, b = PAIRS[pair]
            for reading, value in chosen.items():
                ratio = _ratio(rows, a, b, value)
                if ratio is None:
                    continue
                out.append(f"| {pair.split(' / ')[0]}'s map is smaller than "
                           f"{pair.split(' / ')[1]}'s ({reading}), {seq} at {voxel * 100:g} cm "
                           f"(not a paper sequence unless TUM) | {ratio:.2f}x | exact | up to "
                           f"1/{CLAIMED_SHRINK:g} = {1 / CLAIMED_SHRINK:.2f}x | "
                           f"{'holds' if ratio < 1 else 'does not hold'} |")
    return out
