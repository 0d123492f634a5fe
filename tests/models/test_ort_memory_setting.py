"""The speed sessions' memory setting (issue 54, "Peak memory"): ONNX Runtime's memory pattern
off on the CPU, what the session is built with, the same logits as ONNX Runtime's defaults,
and stated in the speed cell's record."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch
from torch import nn

from evsmap.models.speed_export import (
    SPEED_SESSION_MEMORY,
    session_for,
    session_memory,
    speed_export,
)

ORT_DEFAULTS = {"enable_cpu_mem_arena": True, "enable_mem_pattern": True}


class TinyNet(nn.Module):
    """Enough layers for intermediates the memory pattern would plan."""

    def __init__(self) -> None:
        super().__init__()
        self.a = nn.Conv2d(4, 16, 3, stride=2, padding=1)
        self.b = nn.Conv2d(16, 16, 3, padding=1)
        self.head = nn.Conv2d(16, 6, 1)

    def forward(self, rgb, depth):
        x = torch.relu(self.a(torch.cat([rgb, depth], 1)))
        x = self.head(torch.relu(self.b(x)) + x)
        return nn.functional.interpolate(x, size=rgb.shape[-2:], mode="bilinear",
                                         align_corners=False)


def _inputs(h=192, w=256):
    gen = torch.Generator().manual_seed(1)
    return torch.rand(1, 3, h, w, generator=gen), torch.rand(1, 1, h, w, generator=gen)


@pytest.fixture(scope="module")
def export(tmp_path_factory):
    torch.manual_seed(0)
    net = TinyNet().eval()
    return speed_export(net, _inputs(), ["rgb", "depth"], key="tiny",
                        cache_dir=tmp_path_factory.mktemp("onnx"))


def _session(export, **kw):
    return session_for(export.path, threads=1, free_dimensions=export.free_dimensions(192, 256),
                       **kw)


def _logits(session):
    rgb, depth = (t.numpy() for t in _inputs())
    feeds = {"rgb": rgb, "depth": depth}
    return session.run(None, {i.name: feeds[i.name] for i in session.get_inputs()})[0]


def test_a_cpu_session_keeps_the_arena_and_drops_the_memory_pattern(export):
    options = _session(export).get_session_options()
    assert options.enable_mem_pattern is False
    assert options.enable_cpu_mem_arena is True
    assert session_memory() == dict(SPEED_SESSION_MEMORY) == {
        "enable_cpu_mem_arena": True, "enable_mem_pattern": False}
    assert session_memory(["CPUExecutionProvider"]) == dict(SPEED_SESSION_MEMORY)


def test_an_accelerator_session_keeps_onnx_runtimes_defaults():
    chain = [("CUDAExecutionProvider", {"device_id": 0}), "CPUExecutionProvider"]
    assert session_memory(chain) == {}


def test_explicit_settings_replace_the_speed_setting(export):
    options = _session(export, memory=ORT_DEFAULTS).get_session_options()
    assert options.enable_mem_pattern is True and options.enable_cpu_mem_arena is True
    off = _session(export, memory={"enable_cpu_mem_arena": False}).get_session_options()
    assert off.enable_cpu_mem_arena is False


def test_the_setting_leaves_the_logits_and_labels_unchanged(export):
    default = _logits(_session(export, memory=ORT_DEFAULTS))
    timed = _logits(_session(export))
    np.testing.assert_array_equal(timed, default)
    np.testing.assert_array_equal(timed.argmax(1), default.argmax(1))


def test_a_speed_cell_records_how_its_session_allocates(tmp_path, monkeypatch):
    import evsmap.measure.complexity as complexity
    import evsmap.measure.speed as speed
    import evsmap.models.speed_export as speed_export_module
    import evsmap.runner.network_cells as cells
    from evsmap.models.speed_export import SpeedExport
    from evsmap.runner.context import RunContext
    from evsmap.tables.plan import expand_all

    spec = next(s for s in expand_all() if s.key == "table1/feagnet-v2/speed@640x480[fps]")
    record = SimpleNamespace(contention={}, fps_median=10.0, threads=2, cpu="cpu", gpu=None,
                             runs=3, warmup=2, flag="", rel_ci=0.01, stopped="precision",
                             as_dict=lambda: {"rel_ci": 0.01, "stopped": "precision"})
    timed_modules = []

    def measure_speed(module, *a, **kw):
        timed_modules.append(module)
        return record

    monkeypatch.setattr(speed, "measure_speed", measure_speed)
    monkeypatch.setattr(complexity, "cached_complexity",
                        lambda *a, **kw: SimpleNamespace(flops=1.0))
    monkeypatch.setattr(speed_export_module, "speed_export",
                        lambda *a, **kw: SpeedExport(tmp_path / "x.onnx", True, None))
    monkeypatch.setattr(cells, "run_roofline", lambda ctx: 1.0)
    empty = tmp_path / "data"
    empty.mkdir()
    ctx = RunContext.create(tmp_path / "run", data_root=empty)
    rec = cells.run_speed(spec, ctx)
    assert rec.details["ort_memory"] == {"enable_cpu_mem_arena": True,
                                         "enable_mem_pattern": False}
    # the session holds the weights: the module handed to the timing no longer does
    (module,) = timed_modules
    assert all(p.device.type == "meta" for p in module.parameters())
