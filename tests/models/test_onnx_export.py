import os

import numpy as np
import onnx
import onnxruntime as ort
import pytest
import torch
from torch import nn

import evsmap.models.onnx_export as onnx_export
from evsmap.errors import EvsmapError
from evsmap.measure import OnnxExportError, cached_onnx, export_onnx


class TwoInputNet(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.rgb = nn.Conv2d(3, 8, 3, padding=1)
        self.depth = nn.Conv2d(1, 8, 3, padding=1)
        self.bn = nn.BatchNorm2d(8)
        self.head = nn.Conv2d(8, 5, 1)

    def forward(self, rgb: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        return self.head(torch.sigmoid(self.bn(self.rgb(rgb) + self.depth(depth))))


def make_net() -> TwoInputNet:
    torch.manual_seed(0)
    net = TwoInputNet()
    with torch.no_grad():  # non-trivial batch-norm statistics, so eval vs train differs
        net.bn.running_mean.uniform_(-1, 1)
        net.bn.running_var.uniform_(0.5, 2)
    return net


def inputs(h: int = 12, w: int = 16) -> tuple[torch.Tensor, torch.Tensor]:
    gen = torch.Generator().manual_seed(1)
    return torch.rand(1, 3, h, w, generator=gen), torch.rand(1, 1, h, w, generator=gen)


def run_ort(path, feeds):
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return session.run(None, feeds)[0]


def test_export_matches_torch(tmp_path):
    net = make_net().train()
    x = inputs()
    path = export_onnx(net, x, ("rgb", "depth"), tmp_path / "net.onnx")
    assert path == tmp_path / "net.onnx"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["net.onnx"]  # no external data
    model = onnx.load(str(path))
    assert {o.domain: o.version for o in model.opset_import}.get("", None) == 17
    assert [i.name for i in model.graph.input] == ["rgb", "depth"]
    assert [o.name for o in model.graph.output] == ["logits"]
    assert net.training  # mode restored
    with torch.no_grad():
        expected = net.eval()(*x).numpy()
    got = run_ort(path, {"rgb": x[0].numpy(), "depth": x[1].numpy()})
    assert got.shape == (1, 5, 12, 16)
    np.testing.assert_allclose(got, expected, atol=1e-4)


def test_name_count_mismatch(tmp_path):
    with pytest.raises(ValueError):
        export_onnx(make_net(), inputs(), ("rgb",), tmp_path / "x.onnx")


def test_cache_reuses_and_reexports(tmp_path, monkeypatch):
    calls = []
    real = onnx_export.export_onnx

    def counting(*args, **kwargs):
        calls.append(args[-1])
        return real(*args, **kwargs)

    monkeypatch.setattr(onnx_export, "export_onnx", counting)
    net, x, names = make_net(), inputs(), ("rgb", "depth")
    first = cached_onnx(net, x, names, key="tiny/net v1", cache_dir=tmp_path)
    assert first.parent == tmp_path and first.name.startswith("tiny_net_v1-")
    mtime = first.stat().st_mtime_ns
    again = cached_onnx(net, x, names, key="tiny/net v1", cache_dir=tmp_path)
    assert again == first and first.stat().st_mtime_ns == mtime
    assert len(calls) == 1
    # an equal copy of the weights is the same entry
    twin = make_net()
    assert cached_onnx(twin, x, names, key="tiny/net v1", cache_dir=tmp_path) == first
    assert len(calls) == 1

    with torch.no_grad():
        net.head.weight.add_(0.5)
    changed = cached_onnx(net, x, names, key="tiny/net v1", cache_dir=tmp_path)
    assert changed != first and changed.is_file() and len(calls) == 2
    with torch.no_grad():
        expected = net.eval()(*x).numpy()
    got = run_ort(changed, {"rgb": x[0].numpy(), "depth": x[1].numpy()})
    np.testing.assert_allclose(got, expected, atol=1e-4)

    other_size = cached_onnx(net, inputs(8, 8), names, key="tiny/net v1", cache_dir=tmp_path)
    other_key = cached_onnx(net, x, names, key="another", cache_dir=tmp_path)
    assert len({first, changed, other_size, other_key}) == 4 and len(calls) == 4
    # only finished files, no temporaries left behind
    assert sorted(p.suffix for p in tmp_path.iterdir()) == [".onnx"] * 4


def test_default_cache_dir_from_env(tmp_path, monkeypatch):
    monkeypatch.setenv("EVSMAP_CACHE_DIR", str(tmp_path / "cache"))
    assert onnx_export.default_cache_dir() == tmp_path / "cache" / "onnx"
    path = cached_onnx(nn.Conv2d(1, 2, 1), torch.zeros(1, 1, 4, 4), ("x",), key="c")
    assert path.parent == tmp_path / "cache" / "onnx" and path.is_file()
    monkeypatch.delenv("EVSMAP_CACHE_DIR")
    assert onnx_export.default_cache_dir() == onnx_export.Path.home() / ".cache/evsmap/onnx"


def test_failed_export_raises_and_leaves_nothing(tmp_path):
    class Broken(nn.Module):
        def forward(self, x: torch.Tensor) -> torch.Tensor:
            raise RuntimeError("no way to export this")

    with pytest.raises(OnnxExportError, match="Broken.*no way to export this") as info:
        cached_onnx(Broken(), torch.zeros(1, 1, 2, 2), ("x",), key="broken", cache_dir=tmp_path)
    assert isinstance(info.value, EvsmapError)
    assert "\n" not in str(info.value)
    assert os.listdir(tmp_path) == []
