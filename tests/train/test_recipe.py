"""Recipes: the shipped files, TOML reading, bases, command-line overrides, one-line errors, the
learning-rate schedule at chosen epochs against hand-computed values."""

from __future__ import annotations

import argparse

import pytest

from evsmap.train.recipe import (
    INPUT,
    RecipeError,
    apply_overrides,
    field_names,
    load_recipe,
    parse_size,
    poly_factor,
    recipe_from_dict,
    shipped_recipes,
)


def test_shipped_recipes():
    assert shipped_recipes() == ["paper", "synth-proxy"]


def test_paper_recipe_is_section_iv():
    r = load_recipe("paper")
    assert (r.name, r.source) == ("paper", "paper")
    assert r.epochs == 500 and r.batch_size == 8
    assert r.optimizer == "sgd" and r.momentum == 0.9 and not r.nesterov
    assert r.lr == 0.005 and r.weight_decay == 0.0005
    assert (r.schedule, r.poly_power, r.poly_start_epoch, r.poly_restart) == ("poly", 0.9, 150,
                                                                              False)
    assert r.alpha == 1.0 and r.beta == 1.0 and r.label_smoothing == 0.0 and r.side_weight == 1.0
    assert r.crop == INPUT and r.crop_size((480, 640)) == (480, 640)
    assert r.scale == (1.0, 1.4) and r.flip == 0.5
    assert r.eval_every == 1 and not r.amp


def test_synth_proxy_is_evsmaps_reduced_recipe():
    r = load_recipe("synth-proxy")
    paper = load_recipe("paper")
    assert r.source == "evsmap" and "not the paper" in r.description
    assert 30 <= r.epochs <= 60 and r.batch_size == 8
    assert r.crop_size((480, 640)) == (240, 320)
    assert (r.lr, r.momentum, r.weight_decay) == (paper.lr, paper.momentum, paper.weight_decay)
    assert r.schedule == "poly" and r.poly_power == 0.9
    # the paper's constant share of the schedule (150 / 500) kept: 12 / 40
    assert r.poly_start_epoch / r.epochs == paper.poly_start_epoch / paper.epochs


@pytest.mark.parametrize("name", ["paper", "synth-proxy"])
def test_toml_round_trip(tmp_path, name):
    r = load_recipe(name)
    path = tmp_path / "r.toml"
    path.write_text(r.to_toml())
    assert load_recipe(path) == r
    assert recipe_from_dict(r.as_dict()) == r


def test_base_and_overrides(tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text('base = "paper"\nname = "mine"\nepochs = 10\ncrop = [240, 320]\n')
    r = load_recipe(path)
    assert (r.name, r.epochs, r.crop, r.lr) == ("mine", 10, (240, 320), 0.005)
    # a file-relative base
    child = tmp_path / "child.toml"
    child.write_text('base = "mine.toml"\nname = "child"\nlr = 0.01\n')
    c = load_recipe(child)
    assert (c.epochs, c.lr, c.crop) == (10, 0.01, (240, 320))
    # command-line values: strings for crop and scale, ints for floats
    o = apply_overrides(r, {"crop": "120x160", "scale": "0.5,2", "lr": 1, "epochs": 3,
                            "amp": True})
    assert (o.crop, o.scale, o.lr, o.epochs, o.amp) == ((120, 160), (0.5, 2.0), 1.0, 3, True)
    assert o.name == "mine" and r.crop == (240, 320)  # the original is unchanged
    assert apply_overrides(r, {}) is r


def _one_line(exc: pytest.ExceptionInfo) -> str:
    text = str(exc.value)
    assert "\n" not in text
    return text


@pytest.mark.parametrize("changes, words", [
    ({"lr": -1.0}, ["lr", "(0, inf)"]),
    ({"lr": "fast"}, ["lr", "a number"]),
    ({"epochs": 2.5}, ["epochs", "an integer"]),
    ({"momentum": 1.0}, ["momentum", "[0, 1)"]),
    ({"schedule": "cosine"}, ["schedule", "poly, constant"]),
    ({"optimizer": "adam"}, ["optimizer", "sgd"]),
    ({"scale": [2.0, 1.0]}, ["scale", "min <= max"]),
    ({"scale": [0.5]}, ["scale", "[min, max]"]),
    ({"crop": "big"}, ["crop", "HxW"]),
    ({"crop": [0, 10]}, ["crop[0] (height)"]),
    ({"flip": 1.5}, ["flip", "[0, 1]"]),
    ({"nesterov": "yes"}, ["nesterov", "true or false"]),
    ({"alpha": 0.0, "beta": 0.0}, ["alpha and beta"]),
    ({"workers": -1}, ["workers"]),
    ({"colour": 1}, ["unknown field 'colour'"]),
])
def test_invalid_fields_name_the_field(changes, words):
    with pytest.raises(RecipeError) as exc:
        load_recipe("paper").replace(**changes)
    text = _one_line(exc)
    assert text.startswith("recipe paper: ")
    for word in words:
        assert word in text


def test_file_errors(tmp_path):
    with pytest.raises(RecipeError) as exc:
        load_recipe("nope")
    assert "unknown recipe 'nope'" in _one_line(exc) and "paper, synth-proxy" in str(exc.value)
    with pytest.raises(RecipeError) as exc:
        load_recipe(tmp_path / "missing.toml")
    assert "recipe file not found" in _one_line(exc)
    bad = tmp_path / "bad.toml"
    bad.write_text("epochs = = 3\n")
    with pytest.raises(RecipeError) as exc:
        load_recipe(bad)
    assert "not valid TOML" in _one_line(exc)
    partial = tmp_path / "partial.toml"
    partial.write_text('name = "x"\nepochs = 3\n')
    with pytest.raises(RecipeError) as exc:
        load_recipe(partial)
    assert "missing" in _one_line(exc) and "base" in str(exc.value)
    loop = tmp_path / "loop.toml"
    loop.write_text('base = "loop.toml"\n')
    with pytest.raises(RecipeError) as exc:
        load_recipe(loop)
    assert "loop" in _one_line(exc)
    table = tmp_path / "table.toml"
    table.write_text('base = "paper"\n[optimizer]\nlr = 1\n')
    with pytest.raises(RecipeError) as exc:
        load_recipe(table)
    assert "flat" in _one_line(exc)


def test_parse_size():
    assert parse_size("480x640") == (480, 640) and parse_size("240X320") == (240, 320)
    for bad in ("480", "0x10", "axb", "1x2x3"):
        with pytest.raises(ValueError):
            parse_size(bad)


# -- the schedule -------------------------------------------------------------------------------

def test_paper_schedule_literal_reading():
    """Constant 0.005 for epochs 0-149, then 0.005 * (1 - ep / 500) ** 0.9 with ep the 0-based
    epoch: a drop to 0.005 * 0.7 ** 0.9 at epoch 150, never 0."""
    r = load_recipe("paper")
    hand = {
        0: 0.005,
        1: 0.005,
        149: 0.005,
        150: 0.0036270892,  # 0.005 * 0.7 ** 0.9
        151: 0.0036177611,  # 0.005 * (349 / 500) ** 0.9
        250: 0.0026794337,  # 0.005 * 0.5 ** 0.9
        499: 1.8616456e-05,  # 0.005 * (1 / 500) ** 0.9
    }
    for epoch, lr in hand.items():
        assert r.lr_at(epoch) == pytest.approx(lr, rel=1e-7, abs=0), epoch
    assert r.lr_at(150) == pytest.approx(0.005 * 0.7 ** 0.9, rel=1e-12)


def test_paper_schedule_restart_reading():
    """poly_restart = true: the polynomial counted from epoch 150 over the remaining 350
    epochs, continuous at 150."""
    r = load_recipe("paper").replace(poly_restart=True)
    hand = {
        149: 0.005,
        150: 0.005,
        151: 0.0049871410,  # 0.005 * (1 - 1 / 350) ** 0.9
        325: 0.0026794337,  # 0.005 * 0.5 ** 0.9
        499: 2.5663079e-05,  # 0.005 * (1 / 350) ** 0.9
    }
    for epoch, lr in hand.items():
        assert r.lr_at(epoch) == pytest.approx(lr, rel=1e-7, abs=0), epoch


def test_other_schedules():
    r = load_recipe("paper")
    assert r.replace(schedule="constant").lr_at(499) == 0.005
    assert r.replace(poly_start_epoch=0, epochs=2).lr_at(1) == pytest.approx(0.005 * 0.5 ** 0.9)
    assert poly_factor(3, epochs=10, start=5, power=1.0, restart=False) == 1.0
    assert poly_factor(5, epochs=10, start=5, power=1.0, restart=False) == pytest.approx(0.5)
    assert poly_factor(5, epochs=10, start=5, power=1.0, restart=True) == 1.0


def test_command_line_flags_map_to_fields():
    from evsmap.cli.train_cmd import add_parser, overrides

    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers())
    args = parser.parse_args([
        "train", "feagnet-v1", "--dataset", "d", "--out", "o", "--epochs", "3",
        "--batch-size", "4", "--lr", "0.01", "--crop", "240x320", "--workers", "0", "--amp",
        "--eval-every", "2", "--seed", "7", "--set", "poly_start_epoch=0", "--set",
        "scale=0.5,2.0"])
    got = overrides(args)
    assert got == {"epochs": 3, "batch_size": 4, "lr": 0.01, "crop": "240x320", "workers": 0,
                   "amp": True, "eval_every": 2, "seed": 7, "poly_start_epoch": 0,
                   "scale": "0.5,2.0"}
    assert set(got) <= set(field_names())
    r = apply_overrides(load_recipe("paper"), got)
    assert (r.crop, r.scale, r.poly_start_epoch) == ((240, 320), (0.5, 2.0), 0)
    none = overrides(parser.parse_args(["train", "m", "--dataset", "d", "--out", "o",
                                        "--no-amp"]))
    assert none == {"amp": False}
