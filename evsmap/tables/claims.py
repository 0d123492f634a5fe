"""The paper's comparative claims and the rows they rest on.

The claims and each table's baseline row are data (``paper_tables.toml``: ``baseline``,
``[[tables.<id>.claims]]``, ``own_method``). :data:`CLAIMS` are what ``index.md`` checks as
ratios (:mod:`evsmap.report.claims`); :func:`claims_first` is the order a run measures in, so
that a run stopped early (Ctrl-C, a ``--budget``) has already answered them: the rows the claims
name, the paper's baseline rows (:data:`BASELINES`), the paper's own networks
(:data:`PAPER_NETWORK_PREFIX`), the tables of the paper's own method (``own_method``: the
ablation and the mapping systems) and the mapping runs (:data:`EXTRA_TABLE`) come before the
compared networks.
"""

from __future__ import annotations

from evsmap.tables.load import load_tables
from evsmap.tables.records import Claim

_TABLES = load_tables()

BASELINES: dict[str, str] = {tid: t.baseline for tid, t in _TABLES.items()
                             if t.baseline is not None}
"""The paper's baseline row of each table: the system its method is set against."""

MATCH_TOLERANCE = 0.05

CLAIMS: tuple[Claim, ...] = tuple(c for t in _TABLES.values() for c in t.claims)

PAPER_NETWORK_PREFIX = "feagnet"
"""Row ids of the paper's own networks (FEAGNet-V1/V2/S/L, with their Jetson rows) start so."""

EXTRA_TABLE = "extra"
"""The ``table`` of the mapping runs' records (``extra/mapping/...``): Table IV's cells are read
from them."""

OWN_TABLES: tuple[str, ...] = (*(tid for tid, t in _TABLES.items() if t.own_method), EXTRA_TABLE)
"""Tables (and the mapping runs' ``extra``) whose every row is the paper's method or its
mapping comparison."""

del _TABLES


def claims_first(table: str, row: str) -> int:
    """0 for a cell the paper's claims rest on (module docstring), 1 for the others."""
    if table in OWN_TABLES or row.startswith(PAPER_NETWORK_PREFIX):
        return 0
    if BASELINES.get(table) == row:
        return 0
    if any(c.table == table and row in (c.row, c.base) for c in CLAIMS):
        return 0
    return 1


__all__ = ["BASELINES", "CLAIMS", "EXTRA_TABLE", "MATCH_TOLERANCE", "OWN_TABLES",
           "PAPER_NETWORK_PREFIX", "Claim", "claims_first"]
