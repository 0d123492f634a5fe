"""Speed of the data layer: synthetic rendering and TUM frame loading."""

from __future__ import annotations

import pytest

from evsmap.readers.tum import TumSequence
from evsmap.synth.sequence import SyntheticSequence


@pytest.mark.parametrize("noise", [False, True], ids=["exact", "kinect-noise"])
def test_render_synthetic_frame_640x480(benchmark, noise):
    seq = SyntheticSequence(scene="living_room", seed=0, frames=30, noise=noise)
    seq[0]  # builds the ray-casting scene
    counter = iter(range(10**9))
    benchmark.pedantic(lambda: seq[next(counter) % len(seq)], rounds=15, warmup_rounds=2)


def test_ground_truth_voxels_2cm(benchmark):
    seq = SyntheticSequence(scene="living_room", seed=0, frames=1)
    vox = benchmark.pedantic(seq.ground_truth, args=(0.02,), rounds=3, warmup_rounds=1)
    assert len(vox) > 0


def test_load_tum_frame(benchmark):
    from evsmap.testing import require_sample

    seq = TumSequence(path=require_sample("tum-fr1-xyz"))
    counter = iter(range(10**9))
    benchmark.pedantic(lambda: seq[next(counter) % len(seq)], rounds=30, warmup_rounds=3)
