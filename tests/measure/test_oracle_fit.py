"""Fitting the oracle to a segmenter (evsmap/measure/oracle_fit.py, `evsmap oracle fit`): a
segmenter whose error model is known - an oracle with other settings - is fitted, and the fit
must find those settings."""

from __future__ import annotations

import json

import pytest

from evsmap.cli.main import main
from evsmap.measure import oracle_fit
from evsmap.registry import READERS
from evsmap.segmenters.oracle import OracleSegmenter
from evsmap.segmenters.oracle_profile import load_profile


@pytest.fixture(scope="module")
def rooms():
    return [READERS.create("synthetic", scene=scene, seed=seed, frames=8, width=160,
                           height=120, noise=True, render="cached")
            for scene, seed in (("bedroom", 1), ("office", 2))]


def fitted_to(known, rooms, **kw):
    return oracle_fit.fit_oracle(OracleSegmenter(profile=known, seed=7), rooms,
                                 about={"segmenter": "oracle", "weights": None,
                                        "frames_from": "two tiny rooms"},
                                 search_frames=6, **kw)


def test_the_fit_recovers_a_known_error_model(rooms):
    known = load_profile("per-pixel").replace(
        accuracy=0.7, boundary_accuracy=0.4, error_scale=8.0, world_share=0.8,
        world_scale=0.2, true_second=0.5, confusion="seeded")
    fitted = fitted_to(known, rooms)
    assert abs(fitted.accuracy - 0.7) < 0.05
    assert abs(fitted.boundary_accuracy - 0.4) < 0.06
    assert abs(fitted.true_second - 0.5) < 0.05
    assert fitted.error_scale in (4.0, 8.0, 16.0)
    assert fitted.world_share >= 0.6
    assert abs(fitted.mean_top1["correct"] - 0.80) < 0.02
    # the known oracle's confusers are what the fit reads for each class seen often enough
    seeded = OracleSegmenter(profile=known, seed=7).confusers
    for cls, pairs in fitted.confusers.items():
        if sum(n for _, n in pairs) and fitted.class_accuracy.get(cls) is not None:
            assert pairs[0][0] in seeded[cls]
    net, orc = fitted.fit["network"], fitted.fit["oracle"]
    assert abs(net["persistence"] - orc["persistence"]) < 0.15
    assert abs(net["autocorrelation"]["4"] - orc["autocorrelation"]["4"]) < 0.15


def test_independent_errors_fit_to_no_correlation(rooms):
    known = load_profile("per-pixel").replace(accuracy=0.8)
    fitted = fitted_to(known, rooms)
    assert fitted.error_scale <= 1.0 and fitted.world_share <= 0.2


def test_cli_fit_writes_a_profile_the_oracle_reads(tmp_path, capsys):
    out = tmp_path / "mine.json"
    rc = main(["oracle", "fit", "synthetic", "-r", "frames=4", "-r", "width=160",
               "-r", "height=120", "--segmenter", "oracle", "-s", "profile=per-pixel",
               "-s", "accuracy=0.6", "--search-frames", "3", "--out", str(out)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "| error rate, interior |" in text and str(out) in text
    profile = load_profile(out)
    assert abs(profile.accuracy - 0.6) < 0.06 and profile.fit["segmenter"] == "oracle"
    assert json.loads(out.read_text())["name"] == "mine"
    assert main(["oracle", "show", str(out)]) == 0
    assert "fit: oracle" in capsys.readouterr().out


@pytest.mark.parametrize("argv, message", [
    (["--out", "{tmp}"], "is a folder"),
    (["-r", "frames=2"], "need a SEQUENCE"),
])
def test_cli_fit_refuses_bad_input_in_one_line(tmp_path, capsys, argv, message):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    if "--out" not in argv:
        argv += ["--out", str(tmp_path / "p.json")]
    assert main(["oracle", "fit", "--segmenter", "oracle", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
