"""The tables name model cards; expansion resolves them to the same cells as the option sets the
file held before (``expected_cells.tsv``: every key, config key and requirement)."""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path

import pytest

from evsmap.errors import UnknownNameError
from evsmap.segmenters.model_card import MODEL_CARDS
from evsmap.tables import SegmenterRef, TableSchemaError, expand, expand_all, load_tables
from evsmap.tables.schema import default_path, parse_tables

EXPECTED = Path(__file__).with_name("expected_cells.tsv")


@pytest.fixture(scope="module")
def tables():
    return load_tables()


@pytest.fixture(scope="module")
def raw():
    with open(default_path(), "rb") as f:
        return tomllib.load(f)


def _expected() -> list[tuple[str, str, tuple[str, ...]]]:
    rows = []
    for line in EXPECTED.read_text(encoding="utf-8").splitlines():
        if line and not line.startswith("#"):
            key, config_key, requires = line.split("\t")
            rows.append((key, config_key, tuple(requires.split())))
    return rows


def test_cells_are_those_of_the_option_sets(tables):
    got = [(c.key, c.config_key, c.requires) for c in expand_all(tables)]
    assert got == _expected()


def test_implemented_segmenter_rows_name_cards(raw):
    for tid, table in raw["tables"].items():
        for row in table["rows"]:
            assert "dataset_options" not in row, (tid, row["id"])
            if row.get("segmenter"):
                assert set(row["segmenter"]) <= {"card", "options"}, (tid, row["id"])
                options = row["segmenter"].get("options", {})
                assert set(options) <= {"cfim", "dappf", "attention", "multiscale"}, \
                    (tid, row["id"])  # options are the ablation switches only


def test_a_cell_on_another_dataset_uses_that_datasets_card(tables):
    t1 = {c.key: c for c in expand(tables["table1"])}
    sun = t1["table1/feagnet-v1/accuracy/sunrgbd:test[miou]"].segmenter
    card = MODEL_CARDS.get("feagnet-v1.sunrgbd")
    assert sun.name == card.segmenter and sun.config == card.config == {"num_classes": 37}
    esa = t1["table1/esanet-r34/accuracy/sunrgbd:test[miou]"].segmenter
    assert esa.config == {"dataset": "sunrgbd"}
    comp = t1["table1/feagnet-v1/complexity@640x480[params,flops]"].segmenter
    assert comp.config == {}  # no dataset: the row's own card


def test_ablation_options_go_on_top_of_the_card(tables):
    row = tables["table3"].row("basel")
    assert row.network == SegmenterRef(card="feagnet-v2", options=(
        ("attention", False), ("cfim", False), ("dappf", False), ("multiscale", False)))
    assert row.segmenter_for("sunrgbd").config == {
        "attention": False, "cfim": False, "dappf": False, "multiscale": False,
        "num_classes": 37}


def test_rows_inputs_match_their_cards(tables):
    for table in tables.values():
        for row in table.rows:
            if row.network is None or row.inputs is None:
                continue
            card = MODEL_CARDS.get(row.network.card)
            assert card.uses_depth == (row.inputs == "rgbd"), (table.id, row.id)


def _edit_row(raw, table, index, **changes):
    data = copy.deepcopy(raw)
    data["tables"][table]["rows"][index].update(changes)
    return data


def test_an_unknown_card_names_the_row_and_the_closest_card(raw):
    data = _edit_row(raw, "table1", 10, segmenter={"card": "feagnet-v3"})
    tables = parse_tables(data).tables  # cards are resolved when the table is expanded
    with pytest.raises(TableSchemaError, match=r"table table1, row 'feagnet-v1': unknown model "
                                               r"card 'feagnet-v3'; did you mean 'feagnet-v\d'"):
        expand(tables["table1"])


def test_a_segmenter_is_a_card_or_a_name(raw):
    both = _edit_row(raw, "table1", 10, segmenter={"card": "feagnet-v1", "name": "feagnet-v1"})
    with pytest.raises(TableSchemaError, match=r"table table1, row 'feagnet-v1': segmenter: "
                                               r"give either 'card'"):
        parse_tables(both)


def test_a_named_segmenter_takes_its_options_as_they_are(raw):
    data = _edit_row(raw, "table1", 10, segmenter={"name": "oracle"})
    row = parse_tables(data).tables["table1"].row("feagnet-v1")
    assert row.segmenter_for("sunrgbd").spec == "oracle"
    acc = [c for c in expand(parse_tables(data).tables["table1"]) if c.row == "feagnet-v1"
           and c.kind == "accuracy"]
    assert all(not any(r.startswith("weights:") for r in c.requires) for c in acc)


def test_unknown_card_is_a_user_error():
    with pytest.raises(UnknownNameError):
        SegmenterRef(card="no-such-network").resolve(None)
