"""HarDBlock connection rule and FC-HarDNet-70's published counts."""

from __future__ import annotations

import pytest
import torch

from baselines.fchardnet import fchardnet70
from evsmap.measure.complexity import measure_complexity
from evsmap.models.hardnet import HarDBlock, hard_links, hard_widths


def _params(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def test_links_follow_powers_of_two():
    assert hard_links(1) == [0]
    assert hard_links(2) == [1, 0]
    assert hard_links(3) == [2]
    assert hard_links(4) == [3, 2, 0]
    assert hard_links(6) == [5, 4]
    assert hard_links(8) == [7, 6, 4, 0]
    with pytest.raises(ValueError):
        hard_links(0)


def test_first_block_of_hardnet70():
    # reference: block 1 (input 48, growth 10, 4 layers) has widths 10, 18, 10, 28
    assert hard_widths(48, 10, 1.7, 4) == [48, 10, 18, 10, 28]
    block = HarDBlock(48, 10, 4)
    assert block.kept == [1, 3, 4]
    assert block.out_channels == 48
    out = block(torch.randn(1, 48, 8, 8))
    assert out.shape == (1, 48, 8, 8)
    # layer 4 reads layers 3, 2 and the block input: 10 + 18 + 48 channels
    assert block.layers[3][0].in_channels == 76


@pytest.mark.parametrize("classes, params", [(19, 4_119_257), (40, 4_120_286)])
def test_fchardnet70_parameter_count_is_exact(classes, params):
    model = fchardnet70(num_classes=classes)
    assert _params(model) == params
    assert _params(model.encoder) == 2_378_908


def test_fchardnet70_channel_flow():
    model = fchardnet70()
    assert model.encoder.skip_channels[:4] == [48, 78, 160, 214]
    assert [r[0].in_channels for r in model.reduce] == [534, 374, 238, 126]
    assert [b.out_channels for b in model.up_blocks] == [214, 160, 78, 48]


def test_fchardnet70_flops_match_reference():
    model = fchardnet70(num_classes=40)
    flops = measure_complexity(model, torch.zeros(1, 3, 480, 640)).flops
    assert flops / 1e9 == pytest.approx(5.26, abs=0.005)


def test_fchardnet70_output_size():
    model = fchardnet70(num_classes=3).eval()
    with torch.no_grad():
        assert model(torch.randn(1, 3, 96, 160)).shape == (1, 3, 96, 160)
