"""FEAGNet: the paper's complexity targets (Tables I-III, fvcore, 480x640) and module behaviour."""

from __future__ import annotations

import functools

import pytest
import torch

from evsmap.losses import HybridLoss, MultiScaleLoss
from evsmap.measure.complexity import measure_complexity
from evsmap.models import feagnet as fg
from evsmap.models.feagnet import FEAGNet
from evsmap.models.feagnet_blocks import CFIM, DAPPF, LBU, AxisAttention, CFIMConcat, DAPPFFullRes


def _params(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


@functools.cache
def _count(build_name: str, row: str = "full", readings: tuple = ()) -> tuple[int, int]:
    """(params, fvcore FLOPs at 480x640) of one variant / ablation row, computed once;
    ``readings``: (switch, reading name) pairs replacing the row's ``True`` switches."""
    switches = dict(fg.ABLATIONS[row])
    for key, name in readings:
        if switches.get(key):
            switches[key] = name
    model = getattr(fg, build_name)(num_classes=40, **switches)
    inputs = (torch.zeros(1, 3, 480, 640), torch.zeros(1, 1, 480, 640))
    return _params(model), measure_complexity(model, inputs).flops


# Table III (NYUv2, FEAGNet-V2, 40 classes): params (M) and FLOPs (G) of each ablation row.
TABLE_III = {
    "basel": (3.44, 7.11),
    "basel+cfim": (3.91, 7.11),
    "basel+dappf": (3.70, 7.15),
    "basel+cfim+dappf": (4.17, 7.15),
    "basel+cfim+dappf+waha": (4.45, 7.85),
    "full": (4.45, 7.85),
}


@pytest.mark.parametrize("row", list(TABLE_III))
def test_table_iii_rows_within_5_percent(row):
    params, flops = _count("feagnet_v2", row)
    params_m, flops_g = TABLE_III[row]
    assert params / 1e6 == pytest.approx(params_m, rel=0.05)
    assert flops / 1e9 == pytest.approx(flops_g, rel=0.05)


# Table III's increments (M, G) and the rows they are read between. Two parameter
# increments are documented exceptions (docs/feagnet.md shows the arithmetic of every reading):
# no FLOP-free CFIM reading of the text reaches +0.47 M on HarDNet-70's widths (ours: 4 C^2 per
# stage, +0.368 M), and no HA/WA placement gives +0.28 M together with +0.70 G (ours keeps the
# FLOPs: CCNet's projections on the merged maps, +0.043 M).
INCREMENTS = {
    "cfim": ("basel", "basel+cfim", 0.47, 0.00, 0.368),
    "dappf": ("basel", "basel+dappf", 0.26, 0.04, None),
    "waha": ("basel+cfim+dappf", "basel+cfim+dappf+waha", 0.28, 0.70, 0.043),
}


@pytest.mark.parametrize("module", list(INCREMENTS))
def test_table_iii_increments(module):
    before, after, paper_m, paper_g, exception_m = INCREMENTS[module]
    p0, f0 = _count("feagnet_v2", before)
    p1, f1 = _count("feagnet_v2", after)
    d_params, d_flops = (p1 - p0) / 1e6, (f1 - f0) / 1e9
    # FLOPs: within 5 %, or within the half-unit of the paper's two printed decimals
    assert abs(d_flops - paper_g) <= max(0.05 * paper_g, 0.005)
    if exception_m is None:
        assert d_params == pytest.approx(paper_m, rel=0.05)
    else:  # the documented exception: the reading's own count, so a change shows
        assert d_params == pytest.approx(exception_m, abs=0.0015)


def test_earlier_readings_stay_available_and_cost_what_they_did():
    old = (("cfim", "concat"), ("dappf", "fullres"), ("attention", "lbu"))
    p0, f0 = _count("feagnet_v2", "basel", old)
    p1, f1 = _count("feagnet_v2", "basel+cfim", old)
    assert p1 - p0 == 196_046 and (f1 - f0) / 1e9 == pytest.approx(0.43, abs=0.01)
    p2, f2 = _count("feagnet_v2", "basel+dappf", old)
    assert p2 - p0 == 282_688 and (f2 - f0) / 1e9 == pytest.approx(0.087, abs=0.005)


@pytest.mark.parametrize("build, params_m, flops_g", [
    ("feagnet_v1", 4.5, 1.9), ("feagnet_v2", 4.5, 7.8)])
def test_table_i_within_5_percent(build, params_m, flops_g):
    params, flops = _count(build, "full")
    assert params / 1e6 == pytest.approx(params_m, rel=0.05)
    assert flops / 1e9 == pytest.approx(flops_g, rel=0.05)


@pytest.mark.parametrize("build", [fg.feagnet_s, fg.feagnet_l])
def test_table_ii_rgb_only_variants_within_5_percent(build):
    model = build(num_classes=19)
    assert not model.use_depth and model.depth_encoder is None and model.fusion is None
    assert _params(model) / 1e6 == pytest.approx(2.8, rel=0.05)


def test_v1_differs_from_v2_only_in_init_stride():
    v1, v2 = fg.feagnet_v1(), fg.feagnet_v2()
    assert _params(v1) == _params(v2)
    x = torch.zeros(1, 3, 64, 64)
    assert v2.rgb_encoder.run_stem(x).shape[-2:] == (16, 16)
    assert v1.rgb_encoder.run_stem(x).shape[-2:] == (8, 8)


def test_ablation_switches_remove_their_modules():
    base = fg.feagnet_v2(**fg.ABLATIONS["basel"])
    assert base.fusion is None
    assert isinstance(base.context, torch.nn.Identity)
    assert all(isinstance(s.attention, torch.nn.Identity) for s in base.decoder)
    assert base.side_heads is None
    full = fg.feagnet_v2()
    assert len(full.fusion) == 5  # init layer + four HarDBlock stages
    assert isinstance(full.context, DAPPF)
    assert all(isinstance(s.attention, AxisAttention) for s in full.decoder)
    assert all(len(s.units) == 3 for s in full.decoder)
    assert len(full.side_heads) == 2


@pytest.mark.parametrize("size", [(64, 96), (100, 150), (97, 129)])
def test_eval_output_has_input_size(size):
    model = fg.feagnet_v2(num_classes=7).eval()
    with torch.no_grad():
        out = model(torch.randn(2, 3, *size), torch.randn(2, 1, *size))
    assert out.shape == (2, 7, *size)


def test_training_returns_side_outputs_that_train_with_multiscale_loss():
    torch.manual_seed(0)
    model = fg.feagnet_v2(num_classes=5).train()
    rgb, depth = torch.randn(2, 3, 64, 96), torch.randn(2, 1, 64, 96)
    outputs = model(rgb, depth)
    assert [tuple(o.shape[-2:]) for o in outputs] == [(64, 96), (8, 12), (4, 6)]
    labels = torch.randint(0, 5, (2, 64, 96))
    labels[:, :5] = 255
    loss = MultiScaleLoss(loss=HybridLoss())(outputs, labels)
    loss.backward()
    assert torch.isfinite(loss)
    assert model.side_heads[1].weight.grad.abs().sum() > 0
    assert model.depth_encoder.stem[0][0].weight.grad.abs().sum() > 0


def test_rgbd_model_needs_depth_and_uses_it():
    model = fg.feagnet_v2(num_classes=4).eval()
    rgb = torch.randn(1, 3, 64, 64)
    with pytest.raises(ValueError, match="depth"):
        model(rgb)
    with torch.no_grad():
        a = model(rgb, torch.zeros(1, 1, 64, 64))
        b = model(rgb, torch.randn(1, 1, 64, 64))
    assert not torch.allclose(a, b)


def test_cfim_cross_weights_both_modalities_at_no_map_level_cost():
    torch.manual_seed(0)
    cfim = CFIM(32).eval()
    rgb, depth = torch.randn(1, 32, 8, 8), torch.randn(1, 32, 8, 8)
    with torch.no_grad():
        fused, d_out = cfim(rgb, depth)
        assert fused.shape == rgb.shape and d_out.shape == depth.shape
        # each stream continues weighted by the other modality's gate
        w_rgb = cfim._gate(cfim.fc_rgb, rgb)
        w_depth = cfim._gate(cfim.fc_depth, depth)
        assert torch.allclose(d_out, depth * w_rgb)
        assert torch.allclose(fused, rgb * w_depth + depth * w_rgb)
        assert not torch.allclose(fused, cfim(rgb, depth * 2)[0])
    # two FC layers per modality (v = 1 by default, v = 16 on request), one width-5 1-D conv
    assert cfim.fc_rgb[0].out_features == 32 and cfim.conv1d.kernel_size == (5,)
    assert CFIM(32, reduction=16).fc_depth[0].out_features == 2
    flops = measure_complexity(cfim, (rgb, depth)).flops
    assert flops < 5 * 32 * 32  # the FC layers on pooled vectors only, nothing per pixel


def test_cfim_concat_reading_merges_into_the_rgb_stream():
    torch.manual_seed(0)
    cfim = CFIMConcat(32).eval()
    rgb, depth = torch.randn(1, 32, 8, 8), torch.randn(1, 32, 8, 8)
    with torch.no_grad():
        fused, d_out = cfim(rgb, depth)
    assert fused.shape == rgb.shape and torch.equal(d_out, depth)
    assert cfim.fc[0].out_features == 2


def test_axis_attention_matches_explicit_row_and_column_softmax():
    torch.manual_seed(0)
    att = AxisAttention(8, key_reduction=4, values=2)
    with torch.no_grad():
        att.gamma.fill_(1.0)
        x = torch.randn(1, 8, 3, 4)
        q, k = att.query(x), att.key(x)
        vh, vw = att.value_h(x), att.value_w(x)
        expected = x.clone()
        for w in range(4):  # HA: column w
            a = torch.softmax(q[0, :, :, w].T @ k[0, :, :, w], dim=-1)  # (h, h)
            expected[0, :, :, w] += vh[0, :, :, w] @ a.T
        for h in range(3):  # WA: row h
            a = torch.softmax(q[0, :, h, :].T @ k[0, :, h, :], dim=-1)  # (w, w)
            expected[0, :, h, :] += vw[0, :, h, :] @ a.T
        assert torch.allclose(att(x), expected, atol=1e-5)
        att.gamma.zero_()
        assert torch.equal(att(x), x)


def test_shared_value_attention_uses_one_projection_for_both_directions():
    att = AxisAttention(16)
    assert att.value_w is None and att.query.out_channels == 2  # CCNet: keys C/8, one value
    with torch.no_grad():
        att.gamma.fill_(1.0)
        two = AxisAttention(16, key_reduction=8, values=2)
        two.load_state_dict({**att.state_dict(), "value_w.weight": att.value_h.weight,
                             "value_w.bias": att.value_h.bias})
        x = torch.randn(1, 16, 5, 6)
        assert torch.allclose(att(x), two(x), atol=1e-6)


def test_dappf_and_lbu_keep_shape_on_small_maps():
    lbu = LBU(32, dilation=8).eval()
    for dappf in (DAPPF(32).eval(), DAPPFFullRes(32).eval()):
        with torch.no_grad():
            for size in [(1, 1), (2, 3), (15, 20), (7, 11)]:
                x = torch.randn(1, 32, *size)
                assert dappf(x).shape == x.shape
                assert lbu(x).shape == x.shape
        assert [p[0].dilation for p in (s[1] for s in dappf.process)] == [(4, 1), (8, 1), (12, 1)]


def test_dappf_levels_go_deeper_at_their_pooled_scale():
    dappf = DAPPF(32)
    assert dappf.reduce[0][0].in_channels == 32 and dappf.reduce[1][0].in_channels == 16
    seen = []
    for module in dappf.process:
        module.register_forward_hook(lambda m, i, o: seen.append(tuple(o.shape[-2:])))
    with torch.no_grad():
        dappf.eval()(torch.randn(1, 32, 15, 20))
    assert seen == [(8, 10), (4, 5), (2, 3)]  # V2's 1/32 map pooled by 2, 4, 8


def test_invalid_configuration_is_rejected():
    with pytest.raises(ValueError):
        FEAGNet(num_classes=0)
    with pytest.raises(ValueError, match="cfim='sum'"):
        FEAGNet(cfim="sum")
    with pytest.raises(ValueError):
        FEAGNet(growth=(10, 16, 18), layers=(4, 4, 8), transitions=(64, 96, 160))
