"""Model cards: registered beside their segmenters, resolved by name and dataset, read by the
factories, and every published figure a real cell of the paper tables."""

from __future__ import annotations

import pytest

from evsmap.errors import DuplicateNameError, UnknownNameError
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.model_card import (
    MODEL_CARDS,
    CardRegistry,
    ModelCard,
    PaperFigure,
    WeightFile,
)
from evsmap.segmenters.normalization import INDOOR, SUNRGBD_ESANET
from evsmap.segmenters.official import LAYOUTS
from evsmap.tables import QUANTITIES, load_tables

NETWORKS = ("feagnet-v1", "feagnet-v2", "feagnet-s", "feagnet-l", "esanet-r34-nbt1d",
            "fchardnet-70")


def _card(**changes) -> ModelCard:
    fields = dict(name="net", segmenter="net", description="a network", citation="a paper",
                  dataset="nyuv2", input_size=(480, 640), num_classes=40, class_set="nyuv2-40",
                  uses_depth=True, normalization=INDOOR)
    return ModelCard(**{**fields, **changes})


def test_every_network_has_cards_and_every_card_a_segmenter():
    for name in NETWORKS:
        assert MODEL_CARDS.of_segmenter(name), name
    for card in MODEL_CARDS.items().values():
        assert card.segmenter in SEGMENTERS, card.name
        params = SEGMENTERS.get(card.segmenter).options
        assert set(card.config) <= set(params), card.name


def test_names_and_variants():
    v1 = MODEL_CARDS.get("feagnet-v1")
    assert (v1.dataset, v1.num_classes, v1.input_size, v1.uses_depth) == \
        ("nyuv2", 40, (480, 640), True)
    assert [c.name for c in MODEL_CARDS.of_segmenter("feagnet-v1")] == [
        "feagnet-v1", "feagnet-v1.cityscapes", "feagnet-v1.sunrgbd"]
    assert MODEL_CARDS.for_dataset("feagnet-v1", "sunrgbd").config == {"num_classes": 37}
    assert MODEL_CARDS.for_dataset("feagnet-v1.cityscapes", "nyuv2") is v1
    assert MODEL_CARDS.for_dataset("feagnet-v1", "tum") is v1  # no card for it: itself
    assert MODEL_CARDS.for_dataset("feagnet-v1", None) is v1
    esa = MODEL_CARDS.for_dataset("esanet-r34-nbt1d.nyuv2", "cityscapes")
    assert esa.name == "esanet-r34-nbt1d.cityscapes" and esa.config == {"dataset": "cityscapes"}
    assert esa.input_size == (512, 1024) and esa.class_set == "cityscapes-19"


def test_unknown_card_suggests_the_closest():
    with pytest.raises(UnknownNameError, match=r"unknown model card 'feagnet-v3'; did you mean "
                                               r"'feagnet-v\d'\?"):
        MODEL_CARDS.get("feagnet-v3")


def test_duplicate_card_raises():
    with pytest.raises(DuplicateNameError, match="model card 'feagnet-v2' is already registered"):
        MODEL_CARDS.add(MODEL_CARDS.get("feagnet-v2"))
    registry = CardRegistry()
    registry.add(_card())
    with pytest.raises(DuplicateNameError):
        registry.add(_card(description="another"))
    registry.remove("net")
    assert "net" not in registry._cards


@pytest.mark.parametrize("changes,message", [
    (dict(name="Net"), "lower case"),
    (dict(name="other.nyuv2"), "starts with its segmenter"),
    (dict(num_classes=37), "does not have 37 classes"),
    (dict(input_size=(480, 0)), "input_size"),
])
def test_card_checks_itself(changes, message):
    with pytest.raises(ValueError, match=message):
        _card(**changes)


def test_options_are_sorted_pairs():
    card = _card(options=(("b", 1), ("a", 2)))
    assert card.options == (("a", 2), ("b", 1)) and card.config == {"a": 2, "b": 1}


def test_feagnet_factories_take_their_defaults_from_the_card():
    for name in ("feagnet-v1", "feagnet-v2", "feagnet-s", "feagnet-l"):
        card = MODEL_CARDS.get(name)
        entry = SEGMENTERS.get(name)
        assert entry.options["num_classes"].default == card.num_classes
        assert entry.extras["paper_size"] == card.input_size
        assert entry.description == card.description


@pytest.mark.parametrize("name", ["feagnet-v1.sunrgbd", "feagnet-s", "esanet-r34-nbt1d.sunrgbd",
                                  "fchardnet-70.cityscapes"])
def test_a_segmenter_built_from_a_card_is_the_card(name):
    card = MODEL_CARDS.get(name)
    seg = SEGMENTERS.create(card.segmenter, **card.config)
    assert seg.num_classes == card.num_classes and len(seg.class_names) == card.num_classes
    assert seg.default_size == card.input_size and seg.uses_depth == card.uses_depth
    assert seg.normalization == card.normalization


def test_esanet_normalisation_per_dataset_comes_from_the_cards():
    assert MODEL_CARDS.get("esanet-r34-nbt1d.sunrgbd").normalization is SUNRGBD_ESANET
    with pytest.raises(UnknownNameError, match="unknown dataset 'kitti'"):
        SEGMENTERS.create("esanet-r34-nbt1d", dataset="kitti")


def test_published_figures_are_printed_cells():
    tables = load_tables()
    seen = 0
    for card in MODEL_CARDS.items().values():
        for figure in card.published:
            table, row, column = figure.where
            cell = tables[table].cell(row, column)
            assert tables[table].column(column).quantity == figure.quantity, figure.cell
            assert cell.value is not None, figure.cell  # not a blank cell
            assert figure.quantity in QUANTITIES
            seen += 1
    assert seen >= 20
    v2 = MODEL_CARDS.get("feagnet-v2").figure("params")
    assert tables["table1"].cell(*v2.where[1:]).printed == "4.5"
    assert MODEL_CARDS.get("fchardnet-70.nyuv2").published == ()  # the paper prints none


def test_weight_files_name_a_known_layout():
    files = [w for c in MODEL_CARDS.items().values() for w in c.weights]
    assert {w.dataset for w in files if w.layout == "esanet-release"} == {
        "nyuv2", "sunrgbd", "cityscapes"}
    assert [w.name for w in files if w.layout == "fchardnet-release"] == [
        "hardnet70_cityscapes_model.pkl"]
    assert all(w.layout in LAYOUTS for w in files)
    assert all(isinstance(w, WeightFile) and w.source for w in files)


def test_a_figure_names_a_cell():
    with pytest.raises(ValueError, match="tableN/row/column"):
        PaperFigure(quantity="params", cell="table1/feagnet-v1")


def test_evsmap_list_shows_the_cards(capsys):
    from evsmap.cli.main import main

    assert main(["list"]) == 0
    out = capsys.readouterr().out
    cards = out[out.index("model cards:"):]
    assert "feagnet-v1.sunrgbd" in cards and "sunrgbd-37, RGB-D, 640x480" in cards
    assert "esanet-r34-nbt1d.cityscapes" in cards and "known weight files: 1" in cards
