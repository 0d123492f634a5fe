"""The semantic-detail section: Table IV's map updates, one network feeding all of them, scored
in 3D on ScanNet's labelled meshes (and on the synthetic room, so the comparison is always
there).

The paper says EVSMap "maintains the same level of detail in semantic information
representation" while its map shrinks, and shows pictures (Fig. 7). Here every Table IV update
maps the same frames with the same labels (EVSMap's network with its NYUv2 weights where they
are, else the oracle on the sequence's ground-truth labels), so that the maps differ by the
update alone, and each map is scored against the scene's voxelised ground truth. With one
network, TESAMap and TFEAGMap are the same system (semantic_slam's update), as are MESAMap and
EVSMap (the multi-class Bayesian update): the section has one row for each update, and ORGBMap
for geometry. The records are ordinary mapping runs (``extra/mapping/detail-<row>/...``).

ScanNet scenes: :mod:`evsmap.runner.scannet`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from evsmap.runner.scannet import SCANNET, scannet_scenes, scannet_sequence

if TYPE_CHECKING:  # the report imports this module's names: it stays light (no torch)
    from evsmap.runner.context import RunContext
    from evsmap.runner.mapping_cells import MappingRun

DETAIL_PREFIX = "detail-"
"""What the section's row ids start with."""
DETAIL_ROWS = ("orgbmap", "tesamap", "evsmap")
"""Table IV's rows whose updates the section maps (one network: TFEAGMap maps as TESAMap,
MESAMap as EVSMap)."""
LABELS = {"orgbmap": "ORGBMap", "tesamap": "TESAMap (= TFEAGMap with one network)",
          "evsmap": "EVSMap (printed MVSMMap; = MESAMap with one network)"}
"""The section's row labels: with one network TFEAGMap maps as TESAMap and MESAMap as EVSMap."""
NETWORK_ROW = "evsmap"
"""The row whose network labels every semantic row (EVSMap's FEAGNet-V2, NYUv2 weights)."""
SEMANTIC_DETAIL_TOLERANCE = 0.01
"""The claim "EVSMap keeps TESAMap's semantic detail" holds where EVSMap's 3D scene mIoU is at
most this much (1 point) below TESAMap's, on the same frames and labels."""


def detail_row(row: str) -> str:
    return DETAIL_PREFIX + row


def is_detail(row: str) -> bool:
    """Whether a record's row is one of the section's."""
    return row.startswith(DETAIL_PREFIX)


def detail_runs(ctx: RunContext) -> list[MappingRun]:
    """The section's mapping runs: each of :data:`DETAIL_ROWS` on the synthetic room and on
    each ScanNet scene (one n/a run naming the dataset when it is not under the data root), at
    Table IV's voxel size."""
    from evsmap.runner.mapping_cells import MappingRun
    from evsmap.tables.schema import mapping_table

    table = mapping_table()
    rows = {r.id: r for r in table.rows}
    segmenter = rows[NETWORK_ROW].segmenter_for("nyuv2")
    scenes = scannet_scenes(ctx)
    sequences = ["synthetic"] + ([scannet_sequence(s) for s in scenes] or [SCANNET])
    runs = []
    for seq in sequences:
        for row_id in DETAIL_ROWS:
            system = rows[row_id]
            assert system.updater is not None
            runs.append(MappingRun(detail_row(row_id), LABELS[row_id],
                                   segmenter if system.segmenter is not None else None,
                                   system.updater, seq, ctx.voxel_size))
    return runs


__all__ = ["DETAIL_PREFIX", "DETAIL_ROWS", "LABELS", "NETWORK_ROW", "SEMANTIC_DETAIL_TOLERANCE",
           "detail_row", "detail_runs", "is_detail"]
