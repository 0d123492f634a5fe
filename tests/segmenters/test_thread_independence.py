"""A network segmenter's observation does not depend on torch's thread count; the network's
logits depend on its own thread count (torch's convolutions, ONNX Runtime's) only within a
bound (docs/cli.md, "Thread independence").

Real TUM frames through FEAGNet-V1 (seeded random weights), at the frame's size and resized.
"""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from evsmap.gate.workloads import TorchForward
from evsmap.gate.workloads import digest as gate_digest
from evsmap.registry import READERS, SEGMENTERS
from evsmap.segmenters import resize
from evsmap.segmenters.network import INDOOR, network_inputs

THREADS = (1, 2, 4)
LOGIT_BOUND = 1e-5
"""The largest change of a logit between the network's thread counts, as a share of the largest
logit: measured 4.2e-7 on torch 2.13 and 1.8e-7 on ONNX Runtime (AVX-512, 1, 2 and 4 threads,
three TUM frames)."""


@contextlib.contextmanager
def torch_threads(n: int):
    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


@pytest.fixture(scope="module")
def tum_frames(tum_dir):
    seq = READERS.create("tum", path=str(tum_dir))
    return [seq.frame(i) for i in (0, len(seq) // 2)]


def digest(*arrays: np.ndarray) -> tuple[bytes, ...]:
    return tuple(np.ascontiguousarray(a).tobytes() for a in arrays)


# -- the resize ----------------------------------------------------------------------------------
@pytest.mark.parametrize("shape, size, corners", [
    ((3, 480, 640), (240, 320), False), ((40, 30, 40), (61, 83), False),
    ((40, 30, 40), (480, 640), True), ((2, 1, 9), (4, 3), True), ((3, 7, 5), (1, 1), False)])
def test_bilinear_compiled_and_numpy_agree_bitwise_and_follow_torch(shape, size, corners):
    x = np.random.default_rng(0).standard_normal(shape).astype(np.float32) * 10
    compiled = resize.bilinear(x, size, align_corners=corners)
    plain = resize.bilinear(x, size, align_corners=corners, compiled=False)
    assert compiled.dtype == np.float32 and compiled.shape == (shape[0], *size)
    assert np.array_equal(compiled, plain)
    ref = F.interpolate(torch.from_numpy(x)[None], size=size, mode="bilinear",
                        align_corners=corners)[0].numpy()
    np.testing.assert_allclose(compiled, ref, rtol=0, atol=1e-5 * float(np.abs(x).max()))


def test_bilinear_refuses_a_bad_shape():
    with pytest.raises(ValueError, match="C, h, w"):
        resize.bilinear(np.zeros((4, 4), np.float32), (2, 2))


@pytest.mark.parametrize("size", [(240, 320), (241, 333), (960, 1280)])
def test_network_inputs_are_the_same_bytes_whatever_torch_threads(tum_frames, size):
    """torch's bilinear kernel gave other bits at 1 thread than at 2 for all three sizes."""
    frame = tum_frames[0]
    depth = INDOOR.encode_depth(frame.depth, frame)
    seen = set()
    for n in THREADS:
        with torch_threads(n):
            rgb, d = network_inputs(frame.rgb, depth, INDOOR, size)
        assert rgb.is_contiguous()
        seen.add(digest(rgb.numpy(), d.numpy()))
    assert len(seen) == 1


# -- the observation -----------------------------------------------------------------------------
@pytest.mark.parametrize("size", [(480, 640), (240, 320)], ids=["frame size", "resized"])
def test_observation_is_the_same_bytes_whatever_torch_threads(tum_frames, size):
    """The network at its own thread count (set_threads), torch's intra-op threads of the
    moment 1, 2, 4 (the pipeline's --stage-threads torch): the same classes and probabilities."""
    torch.manual_seed(0)
    seg = SEGMENTERS.create("feagnet-v1", input_size=size)
    assert seg.set_threads(2) == {"network": 2}
    for frame in tum_frames:
        seen = set()
        for n in THREADS:
            with torch_threads(n):
                obs = seg.predict(frame)
                assert torch.get_num_threads() == n  # restored after the forward pass
            seen.add(digest(obs.classes, obs.probs))
        assert len(seen) == 1


@pytest.mark.parametrize("backend", ["torch", "onnxruntime"])
def test_logits_change_with_the_networks_threads_within_the_bound(tum_frames, backend):
    """The one dependence left: the network's own thread count. The logits stay within
    LOGIT_BOUND and a label can only change where its top two logits are that close."""
    torch.manual_seed(0)
    seg = SEGMENTERS.create("feagnet-v1", input_size=(240, 320), backend=backend)
    for frame in tum_frames:
        inputs = seg.preprocess(frame)
        logits = {}
        for n in THREADS:
            seg.set_threads(n)
            logits[n] = seg.logits(inputs).float()[0].numpy()
        scale = float(np.abs(logits[1]).max())
        top2 = np.sort(logits[1], axis=0)[-2:]
        close = (top2[1] - top2[0]) <= 2 * LOGIT_BOUND * scale
        for n in THREADS[1:]:
            assert float(np.abs(logits[n] - logits[1]).max()) <= LOGIT_BOUND * scale
            changed = logits[n].argmax(0) != logits[1].argmax(0)
            assert not (changed & ~close).any()


def test_the_torch_forward_runs_at_the_segmenters_threads(tum_frames, monkeypatch):
    torch.manual_seed(0)
    seg = SEGMENTERS.create("feagnet-v1", input_size=(120, 160))
    seen = []
    real = seg._module.forward

    def spy(*args):
        seen.append(torch.get_num_threads())
        return real(*args)

    monkeypatch.setattr(seg._module, "forward", spy)
    seg.set_threads(3)
    with torch_threads(1):
        seg.predict(tum_frames[0])
        assert torch.get_num_threads() == 1
    seg.set_threads(None)  # torch's count of the moment, as before
    with torch_threads(2):
        seg.predict(tum_frames[0])
    assert seen == [3, 2]


# -- the gates' exact counts ---------------------------------------------------------------------
def test_the_gates_output_sha256_holds_across_thread_counts():
    """docs/gates.md: a network workload's output_sha256 (its per-pixel argmax on seeded inputs)
    does not depend on the intra-op threads the gate runs it with."""
    digests = set()
    for n in THREADS:
        with torch_threads(n):
            job = TorchForward("feagnet-v1", {})
            job.build()
            job.run()
            assert job.output is not None
            labels = job.output[0].argmax(0).numpy().astype(np.int16)
            digests.add(gate_digest(labels))
    assert len(digests) == 1


# -- the runner's segmentation cache -------------------------------------------------------------
def test_the_segmentation_cache_records_the_networks_threads(tum_dir, tmp_path):
    import json

    from evsmap.runner.segcache import SegmentationCache

    seq = READERS.create("tum", path=str(tum_dir))
    torch.manual_seed(0)
    seg = SEGMENTERS.create("feagnet-v1", input_size=(120, 160))
    seg.set_threads(3)
    cache = SegmentationCache(tmp_path)
    with torch_threads(1):
        obs, _, reused = cache.observations(seg, seq, [0], key={"segmenter": "v1"})
    assert not reused
    meta = json.loads(next(tmp_path.glob("obs-*/meta.json")).read_text())
    assert meta["network_threads"] == 3
    with torch_threads(2):  # a fresh prediction at other torch threads: the same bytes
        fresh = seg.predict(seq.frame(0))
    assert digest(obs[0].classes, obs[0].probs) == digest(fresh.classes, fresh.probs)
