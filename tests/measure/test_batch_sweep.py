"""The batch sweep: every network at every batch under one timing rule, FPS per image as batch /
pass time, the ratio to the reference at each batch, and a batch that does not fit recorded
instead of ending the sweep."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch
from torch import nn

from evsmap.measure.batch_sweep import (
    BatchPoint,
    SweepNetwork,
    batch_sweep,
    check_batches,
    is_out_of_memory,
    repeat_batch,
    with_ratios,
)
from evsmap.measure.timing_policy import TimingPolicy

POLICY = TimingPolicy(target_rel_ci=0.2, min_runs=3, budget_s=0.5, max_runs=5, warmup=1,
                      warmup_s=0.0)


def _net(name: str, module: nn.Module | None = None) -> SweepNetwork:
    module = module or nn.Conv2d(3, 4, 3, padding=1)
    module.sweep_name = name  # which network the fake timing was handed
    return SweepNetwork(name, module, (torch.rand(1, 3, 16, 24),), macs=1)


def _fake_measure(ms: dict[str, float], calls: list[tuple[str, int]]):
    """A timing function whose pass takes ``ms[name] * batch`` ms for batch sizes, noting each
    call."""

    def measure(module, inputs, **kw):
        key = module.sweep_name
        batch = inputs[0].shape[0]
        calls.append((key, batch))
        assert kw["policy"] is POLICY and kw["macs"] == batch  # one rule; MACs scale
        return SimpleNamespace(ms_median=ms[key] * (1 + batch) / 2)

    return measure


def test_fps_per_image_is_batch_over_the_pass_and_the_ratio_is_at_the_same_batch():
    calls: list[tuple[str, int]] = []
    sweep = batch_sweep([_net("a"), _net("ref")], batches=(1, 2, 4), reference="ref",
                        policy=POLICY, measure=_fake_measure({"a": 10.0, "ref": 40.0}, calls),
                        roofline=1.0)
    # alternating: both networks at one batch before the next batch
    assert calls == [("a", 1), ("ref", 1), ("a", 2), ("ref", 2), ("a", 4), ("ref", 4)]
    a4 = sweep.point("a", 4)
    assert a4.ms_median == pytest.approx(25.0)  # 10 ms * (1 + 4) / 2
    assert a4.fps_per_image == pytest.approx(4 * 1000 / 25.0)
    assert a4.ratio_to_reference == pytest.approx(4.0)
    assert sweep.point("ref", 2).ratio_to_reference == pytest.approx(1.0)
    assert sweep.networks == ["a", "ref"] and sweep.policy == POLICY.as_dict()


def test_ratios_are_left_out_where_the_reference_was_not_timed():
    points = [BatchPoint("a", 1, 10.0, 100.0), BatchPoint("ref", 1, 20.0, 50.0),
              BatchPoint("a", 2, 10.0, 200.0), BatchPoint("ref", 2, refused="out of memory")]
    ratios = [p.ratio_to_reference for p in with_ratios(points, "ref")]
    assert ratios == [2.0, 1.0, None, None]
    assert all(p.ratio_to_reference is None for p in with_ratios(points, None))


def test_a_real_sweep_times_batched_passes():
    sweep = batch_sweep([_net("conv")], batches=(1, 3), reference="conv", policy=POLICY,
                        threads=1, roofline=1.0)
    for batch in (1, 3):
        p = sweep.point("conv", batch)
        assert p.speed is not None and p.speed.runs >= 3 and p.speed.macs == batch
        assert p.fps_per_image == pytest.approx(batch * 1000.0 / p.ms_median)
        assert p.ratio_to_reference == pytest.approx(1.0)
    assert sweep.as_dict()["points"][1]["batch"] == 3


class FitsUpTo(nn.Module):
    """A conv that raises ``error`` for a batch above ``largest`` (as an allocator would)."""

    def __init__(self, largest: int, error: Exception) -> None:
        super().__init__()
        self.conv = nn.Conv2d(3, 4, 3, padding=1)
        self.largest, self.error = largest, error

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.shape[0] > self.largest:
            raise self.error
        return self.conv(x)


@pytest.mark.parametrize("error", [
    torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 2.00 GiB"),
    MemoryError("cannot allocate"),
    RuntimeError("DefaultCPUAllocator: can't allocate memory: you tried to allocate 99 bytes"),
])
def test_a_batch_that_does_not_fit_is_recorded_and_the_sweep_goes_on(error):
    sweep = batch_sweep([_net("big", FitsUpTo(2, error)), _net("small")], batches=(1, 2, 4, 8),
                        reference="small", policy=POLICY, threads=1, roofline=1.0)
    assert sweep.point("big", 2).fps_per_image is not None
    oom = sweep.point("big", 4)
    assert oom.out_of_memory and oom.fps_per_image is None and oom.ratio_to_reference is None
    assert "\n" not in oom.refused
    assert sweep.point("big", 8).refused == "out of memory at batch 4 (larger not tried)"
    assert sweep.point("small", 8).fps_per_image is not None  # the other network went on


def test_another_error_is_not_taken_for_out_of_memory():
    assert not is_out_of_memory(RuntimeError("mat1 and mat2 shapes cannot be multiplied"))
    with pytest.raises(ValueError, match="boom"):
        batch_sweep([_net("bad", FitsUpTo(0, ValueError("boom")))], batches=(1,),
                    reference=None, policy=POLICY, threads=1, roofline=1.0)


def test_repeat_batch_and_the_sizes_checked():
    rgb, depth = torch.rand(1, 3, 4, 5), torch.rand(1, 1, 4, 5)
    out = repeat_batch((rgb, depth), 3)
    assert [tuple(t.shape) for t in out] == [(3, 3, 4, 5), (3, 1, 4, 5)]
    assert torch.equal(out[0][2], rgb[0]) and out[0].is_contiguous()
    with pytest.raises(ValueError, match="batch 1"):
        repeat_batch(torch.rand(2, 3, 4, 5), 2)
    assert check_batches([1, 2, 4]) == (1, 2, 4)
    for bad in ([], [0, 1], [2, 2]):
        with pytest.raises(ValueError, match="distinct"):
            check_batches(bad)
    with pytest.raises(ValueError, match="reference"):
        batch_sweep([_net("a")], reference="esanet-r34-nbt1d", roofline=1.0)
