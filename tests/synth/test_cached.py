"""The cached rendering of the synthetic room reads back the frames rendered live, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from evsmap.errors import EvsmapError
from evsmap.registry import READERS
from evsmap.synth.cached import CachedSynthetic, cache_folder, cached_ground_truth


@pytest.fixture()
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("EVSMAP_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def test_cached_frames_are_the_live_frames(cache):
    options = dict(frames=3, width=80, height=60)
    live = READERS.create("synthetic", **options)
    cached = READERS.create("synthetic", render="cached", **options)
    assert isinstance(cached, CachedSynthetic) and cached.folder == cache_folder(options)
    assert cached.folder.is_relative_to(cache)
    assert cached.name == live.name and len(cached) == len(live) == 3
    assert cached.class_names == live.class_names and cached.intrinsics == live.intrinsics
    for i in range(3):
        a, b = live.frame(i), cached.frame(i)
        assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.labels, b.labels)
        assert np.array_equal(a.depth, b.depth) and np.array_equal(a.pose, b.pose)
    truth_live, truth_cached = live.ground_truth(0.2), cached.ground_truth(0.2)
    assert np.array_equal(truth_live.keys, truth_cached.keys)


def test_the_rendering_is_reused(cache):
    first = CachedSynthetic(frames=2, width=80, height=60)
    stamp = (first.folder / "rgb.txt").stat().st_mtime_ns
    second = CachedSynthetic(frames=2, width=80, height=60)
    assert second.folder == first.folder
    assert (second.folder / "rgb.txt").stat().st_mtime_ns == stamp


def test_an_unknown_render_mode_is_one_clear_error(cache):
    with pytest.raises(EvsmapError, match="render must be one of live, cached"):
        READERS.create("synthetic", render="gpu")


def test_ground_truth_is_computed_once_and_read_back_bit_for_bit(tmp_path, monkeypatch):
    import numpy as np

    from evsmap.synth import cached
    from evsmap.synth.sequence import SyntheticSequence

    monkeypatch.setenv("EVSMAP_CACHE_DIR", str(tmp_path))
    options = {"frames": 2, "width": 64, "height": 48}
    fresh = SyntheticSequence(**options).ground_truth(0.1)
    first = cached.cached_ground_truth(options, 0.1)
    assert list(cached.cache_folder(options).glob("groundtruth-*.npz"))
    calls = []
    monkeypatch.setattr(SyntheticSequence, "ground_truth",
                        lambda self, r: calls.append(r))  # a second compute would show here
    again = cached.cached_ground_truth(options, 0.1)
    assert calls == []
    for truth in (first, again):
        assert np.array_equal(truth.keys, fresh.keys) and truth.keys.dtype == fresh.keys.dtype
        assert np.array_equal(truth.labels, fresh.labels)
        assert truth.labels.dtype == fresh.labels.dtype and truth.resolution == 0.1


def test_the_frames_identity_ignores_what_is_cached_beside_the_frames(cache):
    from evsmap.runner.mapping_labels import sequence_identity

    seq = CachedSynthetic(frames=2, width=80, height=60)
    before = sequence_identity(seq)
    cached_ground_truth({"frames": 2, "width": 80, "height": 60}, 0.1)  # written beside them
    assert sequence_identity(CachedSynthetic(frames=2, width=80, height=60)) == before
    assert str(seq.folder.resolve()) in before
