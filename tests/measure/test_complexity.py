import logging
import warnings

import pytest
import torch
from torch import nn

from evsmap.measure import ComplexityRecord, measure_complexity


class TwoInputNet(nn.Module):
    """RGB and depth branches, summed, a sigmoid (fvcore cannot count it), a 1x1 head."""

    def __init__(self, classes: int = 4) -> None:
        super().__init__()
        self.rgb = nn.Conv2d(3, 8, 3, padding=1)
        self.depth = nn.Conv2d(1, 8, 3, padding=1)
        self.head = nn.Conv2d(8, classes, 1)

    def forward(self, rgb: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        return self.head(torch.sigmoid(self.rgb(rgb) + self.depth(depth)))


def inputs(h: int = 16, w: int = 16) -> tuple[torch.Tensor, torch.Tensor]:
    return torch.rand(1, 3, h, w), torch.rand(1, 1, h, w)


def test_single_conv_hand_count():
    net = nn.Conv2d(3, 8, 3, padding=1)
    rec = measure_complexity(net, torch.zeros(1, 3, 16, 16))
    assert isinstance(rec, ComplexityRecord)
    assert rec.params == 3 * 8 * 9 + 8
    assert rec.conv_macs == 3 * 8 * 9 * 256
    assert rec.flops == rec.conv_macs  # fvcore: one MAC = one flop, bias not counted
    assert rec.uncounted_ops == {}
    assert (rec.height, rec.width) == (16, 16)


def test_two_input_net_hand_count_and_uncounted_ops():
    rec = measure_complexity(TwoInputNet(), inputs(16, 12))
    assert rec.params == (3 * 8 * 9 + 8) + (1 * 8 * 9 + 8) + (8 * 4 + 4)
    pixels = 16 * 12
    assert rec.conv_macs == (3 * 8 * 9 + 1 * 8 * 9 + 8 * 4) * pixels
    assert rec.by_operator["conv"] == rec.conv_macs
    assert rec.flops == sum(rec.by_operator.values())
    assert rec.uncounted_ops.get("aten::sigmoid") == 1
    assert rec.uncounted_ops.get("aten::add") == 1
    assert (rec.height, rec.width) == (16, 12)
    d = rec.as_dict()
    assert d["params"] == rec.params and d["uncounted_ops"] == rec.uncounted_ops


def test_frozen_and_shared_parameters():
    conv = nn.Conv2d(2, 2, 1)
    net = nn.Sequential(conv, conv, nn.Conv2d(2, 3, 1))
    net[2].weight.requires_grad_(False)
    rec = measure_complexity(net, torch.zeros(1, 2, 4, 4))
    assert rec.params == (4 + 2) + (6 + 3)  # shared conv once, frozen weights included
    assert rec.conv_macs == (4 + 4 + 6) * 16


def test_counts_in_eval_mode_and_restores_modes():
    class ModeNet(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.conv = nn.Conv2d(1, 2, 1)
            self.seen = []

        def forward(self, x: torch.Tensor) -> torch.Tensor:
            self.seen.append(self.training)
            return self.conv(x)

    net = ModeNet().train()
    net.conv.eval()  # a mixed state must come back as it was
    measure_complexity(net, torch.zeros(1, 1, 4, 4))
    assert net.seen and not any(net.seen)
    assert net.training is True and net.conv.training is False


def test_fvcore_messages_are_silenced(caplog):
    with warnings.catch_warnings(record=True) as caught, caplog.at_level(logging.DEBUG):
        warnings.simplefilter("always")
        rec = measure_complexity(TwoInputNet(), inputs(8, 8))
    assert rec.uncounted_ops  # there was something to warn about
    assert not [r for r in caplog.records if r.name.startswith("fvcore")]
    assert not caught
    assert logging.getLogger("fvcore.nn.jit_analysis").level == logging.NOTSET


def test_rejects_bad_inputs():
    with pytest.raises(TypeError):
        measure_complexity(nn.Conv2d(1, 1, 1), [])
