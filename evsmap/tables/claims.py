"""The paper's comparative claims and the rows they rest on.

:data:`CLAIMS` are what ``index.md`` checks as ratios (:mod:`evsmap.report.claims`);
:func:`claims_first` is the order a run measures in, so that a run stopped early (Ctrl-C, a
``--budget``) has already answered them: the rows the claims name, the paper's baseline rows
(:data:`BASELINES`), the paper's own networks (:data:`PAPER_NETWORK_PREFIX`), Table III (the
paper's ablation) and Table IV (its mapping systems) come before the compared networks.
"""

from __future__ import annotations

from dataclasses import dataclass

BASELINES = {"table1": "esanet-r34", "table2": "esanet-r34", "table4": "tesamap"}
"""The paper's baseline row of each table: the system its method is set against."""


@dataclass(frozen=True)
class Claim:
    """A comparative claim of the paper about ``value(row, column) / value(base, column)``:
    above 1 (``mode="higher"``), below 1 (``"lower"``), or within :data:`MATCH_TOLERANCE` of
    the paper's own ratio (``"match"``: the paper trades accuracy for speed, so what it claims
    is its relative accuracy, not a win)."""

    text: str
    table: str
    row: str
    base: str
    column: str
    mode: str


MATCH_TOLERANCE = 0.05


CLAIMS = (
    Claim("FEAGNet-V2 runs faster than ESANet-R34 (Table I, FPS)", "table1", "feagnet-v2",
          "esanet-r34", "fps", "higher"),
    Claim("FEAGNet-V1 runs faster than ESANet-R34 (Table I, FPS)", "table1", "feagnet-v1",
          "esanet-r34", "fps", "higher"),
    Claim("FEAGNet-V2 has fewer parameters than ESANet-R34 (Table I)", "table1", "feagnet-v2",
          "esanet-r34", "params", "lower"),
    Claim("FEAGNet-V2 needs fewer FLOPs than ESANet-R34 (Table I)", "table1", "feagnet-v2",
          "esanet-r34", "flops", "lower"),
    Claim("FEAGNet-V2 keeps the paper's share of ESANet-R34's NYUv2 mIoU (Table I, within 5 %)",
          "table1", "feagnet-v2", "esanet-r34", "miou_nyuv2", "match"),
    Claim("FEAGNet-V2 keeps the paper's share of ESANet-R34's SUN RGB-D mIoU (Table I, within "
          "5 %)", "table1", "feagnet-v2", "esanet-r34", "miou_sunrgbd", "match"),
    Claim("EVSMap runs faster end to end than TESAMap (Table IV, Runtime)", "table4", "evsmap",
          "tesamap", "runtime", "higher"),
    Claim("EVSMap's map is smaller than TESAMap's on Seq.1, TUM (Table IV)", "table4", "evsmap",
          "tesamap", "size_seq1", "lower"),
)


PAPER_NETWORK_PREFIX = "feagnet"
"""Row ids of the paper's own networks (FEAGNet-V1/V2/S/L, with their Jetson rows) start so."""

OWN_TABLES = ("table3", "table4", "extra")
"""Tables (and the mapping runs' ``extra``) whose every row is the paper's method or its
mapping comparison."""


def claims_first(table: str, row: str) -> int:
    """0 for a cell the paper's claims rest on (module docstring), 1 for the others."""
    if table in OWN_TABLES or row.startswith(PAPER_NETWORK_PREFIX):
        return 0
    if BASELINES.get(table) == row:
        return 0
    if any(c.table == table and row in (c.row, c.base) for c in CLAIMS):
        return 0
    return 1
