"""The warm-up before a timed mapping loop: the update's kernels are loaded on a scratch copy
of the empty map, so the map itself is what the loop alone builds."""

from __future__ import annotations

import pytest

from evsmap.measure.engine import run_mapping
from evsmap.measure.evaluators import MapFiles
from evsmap.registry import READERS, SEGMENTERS, UPDATERS


@pytest.fixture(scope="module")
def seq():
    return READERS.create("synthetic", frames=3, width=80, height=60)


@pytest.mark.parametrize("updater", ["multiclass-bayes", "octomap-cpp"])
def test_the_warm_up_leaves_the_map_as_the_loop_builds_it(tmp_path, seq, updater,
                                                          monkeypatch):
    if updater == "octomap-cpp":
        pytest.importorskip("octomap")
    seg = SEGMENTERS.create("oracle")
    integrated = []
    files = {}
    for warm in (0, 1):
        the_map = UPDATERS.create(updater, resolution=0.1)
        cls = type(the_map)
        original = cls.integrate

        def counting(self, f, o=None, *, the_map=the_map, original=original):
            integrated.append(self is the_map)
            return original(self, f, o)

        monkeypatch.setattr(cls, "integrate", counting)
        out = tmp_path / f"{warm}.ot"
        run = run_mapping(seq, the_map, observations=[seg.predict(seq.frame(i))
                                                      for i in range(3)],
                          warmup=warm, measure_memory=False, evaluators=[MapFiles(out=out)])
        monkeypatch.setattr(cls, "integrate", original)
        files[warm] = out.read_bytes()
        assert run.indices == [0, 1, 2] and len(run.times.get("update")) == 3
    assert files[1] == files[0]
    if updater == "multiclass-bayes":  # one integration of a scratch copy, then the loop's
        assert integrated == [True] * 3 + [False] + [True] * 3
    else:  # a C++ map cannot be copied: not warmed
        assert integrated == [True] * 6
