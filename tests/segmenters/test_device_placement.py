"""``NetworkSegmenter.place``: the device and autocast precision a network runs at, what its
records say, and its refusals (int8 on a GPU, autocast on ONNX Runtime, a GPU that is not
here)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from evsmap.devices import DeviceUnavailableError
from evsmap.errors import InvalidDataError
from evsmap.synth.sequence import SyntheticSequence
from tests.segmenters.int8_net import SIZE, tiny_segmenter


@pytest.fixture(scope="module")
def frame():
    return SyntheticSequence(frames=1, width=SIZE[1] * 2, height=SIZE[0] * 2).frame(0)


def test_bf16_autocast_on_the_cpu_agrees_with_fp32_on_most_pixels(frame):
    fp32 = tiny_segmenter(num_classes=40)
    bf16 = tiny_segmenter(num_classes=40)
    bf16.module.load_state_dict(fp32.module.state_dict())
    bf16.place(precision="bf16")
    assert bf16.logits(bf16.preprocess(frame)).dtype == torch.bfloat16
    a, b = fp32.predict(frame), bf16.predict(frame)
    assert b.probs.dtype == np.float32 and b.classes.shape == a.classes.shape
    assert (a.classes[..., 0] == b.classes[..., 0]).mean() > 0.8
    assert bf16.precision_record() == {"precision": "bf16"}


def test_place_refusals():
    seg = tiny_segmenter(num_classes=40, backend="onnxruntime")
    with pytest.raises(InvalidDataError, match="torch backend only"):
        seg.place(precision="fp16")
    if not torch.cuda.is_available():
        with pytest.raises(DeviceUnavailableError, match="--device cuda"):
            tiny_segmenter(num_classes=40).place(device="cuda")
    seg = tiny_segmenter(num_classes=40)
    seg.place(device="cpu")
    assert seg.device == "cpu" and "device" not in seg.precision_record()
