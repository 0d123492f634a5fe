"""The speed cells' export: one size-free lean graph per network, checked against torch at a
size it was not traced at, a fixed-size fallback where the graph bakes a size, and a cache."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from torch import nn

from evsmap.models.speed_export import (
    export_lean,
    session_for,
    speed_export,
    structure_digest,
    trace_sizes,
)


class FreeNet(nn.Module):
    """A graph that works at any size (the upsampling follows the input)."""

    def __init__(self) -> None:
        super().__init__()
        self.conv = nn.Conv2d(4, 8, 3, stride=2, padding=1)
        self.bn = nn.BatchNorm2d(8)
        self.head = nn.Conv2d(8, 5, 1)

    def forward(self, rgb, depth):
        x = self.head(torch.relu(self.bn(self.conv(torch.cat([rgb, depth], 1)))))
        return nn.functional.interpolate(x, size=rgb.shape[-2:], mode="bilinear",
                                         align_corners=False)


class BakedNet(FreeNet):
    """The same, but the output size is a Python number at trace time (baked in)."""

    def forward(self, rgb, depth):
        x = self.head(torch.relu(self.bn(self.conv(torch.cat([rgb, depth], 1)))))
        h, w = int(rgb.shape[-2]), int(rgb.shape[-1])
        return nn.functional.interpolate(x, size=(h, w), mode="bilinear", align_corners=False)


def _inputs(h=256, w=320):
    gen = torch.Generator().manual_seed(0)
    return torch.rand(1, 3, h, w, generator=gen), torch.rand(1, 1, h, w, generator=gen)


def _net(cls):
    torch.manual_seed(0)
    net = cls().eval()
    with torch.no_grad():
        net.bn.running_mean.uniform_(-0.5, 0.5)
        net.bn.running_var.uniform_(0.5, 2.0)
    return net


def _ort(export, inputs):
    h, w = inputs[0].shape[-2:]
    session = session_for(export.path, threads=1, free_dimensions=export.free_dimensions(h, w))
    names = ["rgb", "depth"]
    feeds = {i.name: inputs[names.index(i.name)].numpy() for i in session.get_inputs()}
    return session.run(None, feeds)[0]


def test_one_size_free_export_serves_every_size_and_is_cached(tmp_path):
    net = _net(FreeNet)
    first = speed_export(net, _inputs(), ["rgb", "depth"], key="free", cache_dir=tmp_path)
    assert first.size_free and first.export_s is not None and first.note == ""
    assert first.path.with_name(first.path.name + ".data").is_file()  # the weights beside it
    for size in ((256, 320), (320, 448)):
        inputs = _inputs(*size)
        with torch.no_grad():
            expected = net(*inputs).numpy()
        np.testing.assert_allclose(_ort(first, inputs), expected, rtol=1e-4, atol=1e-5)
    other = speed_export(net, _inputs(320, 448), ["rgb", "depth"], key="free",
                         cache_dir=tmp_path)
    assert other.path == first.path and other.export_s is None  # the other size: same file
    assert sorted(p.suffix for p in tmp_path.iterdir()) == [".data", ".onnx"]


def test_a_baked_size_falls_back_to_a_fixed_size_export_and_says_why(tmp_path):
    net = _net(BakedNet)
    export = speed_export(net, _inputs(), ["rgb", "depth"], key="baked", cache_dir=tmp_path)
    assert not export.size_free and "fixed-size export" in export.note
    assert export.free_dimensions(256, 320) == {}
    with torch.no_grad():
        expected = net(*_inputs()).numpy()
    np.testing.assert_allclose(_ort(export, _inputs()), expected, rtol=1e-4, atol=1e-5)
    # the refusal is remembered: the next size does not try the size-free export again
    refused = [p for p in tmp_path.iterdir() if p.name.endswith(".fixed.json")]
    assert len(refused) == 1 and "baked" in json.loads(refused[0].read_text())["why"]
    again = speed_export(net, _inputs(320, 448), ["rgb", "depth"], key="baked",
                         cache_dir=tmp_path)
    assert not again.size_free and again.path != export.path


def test_the_lean_graph_equals_the_network_and_holds_no_weight_inline(tmp_path):
    import onnx

    net = _net(FreeNet)
    path = tmp_path / "net.onnx"
    export_lean(net, _inputs(), ["rgb", "depth"], path, size_free=False)
    model = onnx.load(str(path), load_external_data=False)
    assert {i.name for i in model.graph.input} == {"rgb", "depth"}
    assert model.graph.initializer and all(
        t.data_location == onnx.TensorProto.EXTERNAL for t in model.graph.initializer)


def test_digest_follows_structure_not_weights():
    a, b = _net(FreeNet), _net(FreeNet)
    with torch.no_grad():
        b.conv.weight.add_(1.0)
    assert structure_digest(a) == structure_digest(b)
    assert structure_digest(a) != structure_digest(_net(BakedNet))


@pytest.mark.parametrize("size,traced,checked", [((480, 640), (192, 320), (256, 256)),
                                                 ((1024, 2048), (512, 1024), (576, 960)),
                                                 ((96, 96), (128, 128), (192, 64))])
def test_trace_sizes(size, traced, checked):
    assert trace_sizes(size) == (traced, checked)


class PooledNet(FreeNet):
    """Pools to a fixed grid: the exporter refuses it with free sizes (as ESANet's and LDN's
    context modules), printing the traced graph from C++."""

    def __init__(self) -> None:
        super().__init__()
        self.pool = nn.AdaptiveAvgPool2d((4, 4))

    def forward(self, rgb, depth):
        x = self.conv(torch.cat([rgb, depth], 1))
        x = x + nn.functional.interpolate(self.pool(x), size=x.shape[-2:], mode="nearest")
        return self.head(x)


def test_a_refused_size_free_export_falls_back_quietly(tmp_path, capfd):
    export = speed_export(_net(PooledNet), _inputs(), ["rgb", "depth"], key="pooled",
                          cache_dir=tmp_path)
    assert not export.size_free and "adaptive_avg_pool2d" in export.note
    out, err = capfd.readouterr()
    assert "Torch IR graph" not in out + err and len(out + err) < 2000
