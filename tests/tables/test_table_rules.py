"""What each table is (its numeral, role, baseline, claims) is data in ``paper_tables.toml``;
code asks the loaded tables, and a rule that names no row of its table is one line."""

from __future__ import annotations

import pytest

from evsmap.tables.claims import BASELINES, CLAIMS, OWN_TABLES, claims_first
from evsmap.tables.schema import (
    load_tables,
    mapping_table,
    mapping_table_id,
    table_ids,
    table_numbers,
)


def test_the_tables_say_what_they_are():
    tables = load_tables()
    assert table_ids() == tuple(tables)
    assert table_numbers() == {t.number: tid for tid, t in tables.items()}
    assert mapping_table() is not None and mapping_table().role == "mapping"
    assert mapping_table().number == "IV"
    assert [t.number for t in tables.values() if t.role == "networks"] == ["I", "II"]
    assert [t.number for t in tables.values() if t.trained_beside] == ["I", "III"]
    assert {tables[tid].number: row for tid, row in BASELINES.items()} == {
        "I": "esanet-r34", "II": "esanet-r34", "IV": "tesamap"}
    assert OWN_TABLES[-1] == "extra"
    assert [tables[t].number for t in OWN_TABLES[:-1]] == ["III", "IV"]


def test_claims_compare_to_their_tables_baseline():
    tables = load_tables()
    assert len(CLAIMS) == 8
    for claim in CLAIMS:
        table = tables[claim.table]
        assert claim.base == table.baseline
        table.cell(claim.row, claim.column)  # both exist
        assert claims_first(claim.table, claim.row) == 0
        assert claims_first(claim.table, claim.base) == 0


def test_mapping_table_among_given_tables():
    tables = load_tables()
    networks = {tid: t for tid, t in tables.items() if t.role == "networks"}
    assert mapping_table_id(networks) is None
    with pytest.raises(KeyError):
        mapping_table(networks)
    assert mapping_table_id(tables) == mapping_table().id
