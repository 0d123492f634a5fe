"""FEAGNet, the RGB-D segmentation network of "EVSMaP: An Efficient Volumetric-Semantic Mapping
Approach for Embedded Systems" (Section III-A, Fig. 2-5, Tables I-III).

Two symmetric FC-HarDNet-70 encoders (RGB and depth) of five stages - the init layer and four
HarDBlocks, as FASSD-Net keeps them - exchange information through a Cross-Modal Feature
Interaction Module (CFIM) after every stage. A Dilated Asymmetric Pooling Pyramid Fusion module
(DAPPF) aggregates context on the last encoder output, and a Lightweight Attention Decoder (LAD)
of three stages returns to 1/4 resolution; each stage runs three Lightweight Bottleneck Units at
its input resolution, upsamples x2, merges the encoder skip and applies height- and
width-direction attention to the merged map. A 1x1 convolution and bilinear upsampling restore
the input size. Training adds multi-scale supervision heads.

Each module has the reading that fits its own Table III row by default and the earlier readings
as named options (:data:`CFIM_READINGS`, :data:`DAPPF_READINGS`, :data:`ATTENTION_READINGS`).
The paper leaves most module internals open; every choice made here, with the sentence it serves,
the lineage it follows and the arithmetic against Table III, is written down in
``docs/feagnet.md``."""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from evsmap.models.hardnet import HarDNetEncoder
from evsmap.models.layers import ConvBNReLU, StridedLogits, resize_to

# ---------------------------------------------------------------------------------------------
# blocks


class CFIM(nn.Module):
    """Cross-Modal Feature Interaction Module (Fig. 3), the FLOP-free "cross" reading (default).

    Global average pooling of both modalities; on each pooled descriptor two fully connected
    layers ``C -> C/v -> C`` (``v = reduction``), then one shared 1-D convolution of width 5
    across the channels; sigmoid gates. The gates are cross-multiplied: the depth gate weights
    the RGB features and the RGB gate the depth features. The RGB stream continues with the
    sum of the two cross-weighted maps (the baseline adds the two maps unweighted), the depth
    stream with its own cross-weighted map, so each stream's output is "weighted by CFIM and
    fed into the next encoder block" (Fig. 2) and the module costs no multiply-accumulate at
    the feature maps' resolution (Table III: "+0.00 G").

    ``reduction`` defaults to 1: the layer widths that come closest to Table III's +0.47 M
    (``docs/feagnet.md`` shows the arithmetic of every reading; the paper's ``v = 16`` gives
    0.05 M).

    Args:
        channels: channels ``C`` of both inputs.
        reduction: ``v``, the FC bottleneck ratio.
        kernel_size: width of the 1-D channel convolution (5 in the paper).
    """

    def __init__(self, channels: int, *, reduction: int = 1, kernel_size: int = 5) -> None:
        super().__init__()
        hidden = max(channels // reduction, 1)

        def fc() -> nn.Sequential:
            return nn.Sequential(nn.Linear(channels, hidden), nn.ReLU(inplace=True),
                                 nn.Linear(hidden, channels))

        self.fc_rgb, self.fc_depth = fc(), fc()
        self.conv1d = nn.Conv1d(1, 1, kernel_size, padding=kernel_size // 2, bias=False)

    def _gate(self, fc: nn.Module, x: torch.Tensor) -> torch.Tensor:
        b, c = x.shape[:2]
        g = self.conv1d(fc(x.mean(dim=(2, 3))).unsqueeze(1))
        return torch.sigmoid(g).view(b, c, 1, 1)

    def forward(self, rgb: torch.Tensor, depth: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """Returns (RGB stream, depth stream) for the next encoder stage."""
        w_rgb, w_depth = self._gate(self.fc_rgb, rgb), self._gate(self.fc_depth, depth)
        depth_out = depth * w_rgb
        return rgb * w_depth + depth_out, depth_out


class CFIMConcat(nn.Module):
    """CFIM, the "concat" reading (``cfim="concat"``; evsmap's default before the Table III
    row fit): SE gate (FC ``C -> C/16 -> C``) on the RGB descriptor, ECA gate (1-D conv of width
    5) on the depth descriptor, each gate re-weighting the other modality, the two re-weighted
    maps concatenated and merged by a 1x1 conv-BN-ReLU into the RGB stream; the depth stream
    continues with its own features. 0.20 M parameters and 0.43 G at 480x640 (V2), most of it
    the merge at 1/4 resolution.

    Args:
        channels: channels ``C`` of both inputs.
        reduction: ``v``, the FC bottleneck ratio.
        kernel_size: width of the 1-D channel convolution.
    """

    def __init__(self, channels: int, *, reduction: int = 16, kernel_size: int = 5) -> None:
        super().__init__()
        hidden = max(channels // reduction, 1)
        self.fc = nn.Sequential(
            nn.Linear(channels, hidden), nn.ReLU(inplace=True), nn.Linear(hidden, channels))
        self.conv1d = nn.Conv1d(1, 1, kernel_size, padding=kernel_size // 2, bias=False)
        self.merge = ConvBNReLU(2 * channels, channels, 1)

    def forward(self, rgb: torch.Tensor, depth: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        b, c = rgb.shape[:2]
        w_rgb = torch.sigmoid(self.fc(rgb.mean(dim=(2, 3)))).view(b, c, 1, 1)
        w_depth = torch.sigmoid(self.conv1d(depth.mean(dim=(2, 3)).unsqueeze(1))).view(b, c, 1, 1)
        return self.merge(torch.cat([rgb * w_depth, depth * w_rgb], dim=1)), depth


CFIM_READINGS = {"cross": CFIM, "concat": CFIMConcat}
"""CFIM readings by name (``cfim=``): the default first."""


class AsymmetricSeparableConv(nn.Sequential):
    """Depthwise 3x1 then depthwise 1x3 convolution (both with ``dilation``), then a pointwise
    1x1 conv-BN-ReLU: an asymmetric depthwise separable convolution. ``norm=False``: the
    pointwise conv carries a bias and no batch norm (for maps of a few pixels, where batch
    statistics over a batch of single pixels blow up the gradients)."""

    def __init__(self, channels: int, *, dilation: int = 1, norm: bool = True) -> None:
        super().__init__(
            nn.Conv2d(channels, channels, (3, 1), padding=(dilation, 0), dilation=(dilation, 1),
                      groups=channels, bias=False),
            nn.Conv2d(channels, channels, (1, 3), padding=(0, dilation), dilation=(1, dilation),
                      groups=channels, bias=False),
            ConvBNReLU(channels, channels, 1) if norm else _conv_relu(channels, channels),
        )


def _conv_relu(in_channels: int, out_channels: int) -> nn.Sequential:
    """1x1 conv with bias, then ReLU: no batch norm."""
    return nn.Sequential(nn.Conv2d(in_channels, out_channels, 1), nn.ReLU(inplace=True))


class _Pyramid(nn.Module):
    """The parts both DAPPF readings have (declared for the type checker; set by
    :func:`_pyramid_setup` and the readings' constructors)."""

    pools: tuple[tuple[int, int], ...]
    base: ConvBNReLU
    fuse: ConvBNReLU
    relu: nn.ReLU
    reduce: nn.ModuleList
    process: nn.ModuleList


def _pyramid_setup(module: _Pyramid, channels: int, compression: int,
                   pools: tuple[tuple[int, int], ...], dilations: tuple[int, ...]) -> int:
    """What both DAPPF readings share: the level check, the 1x1 branch, the fusion of the
    branches back to ``channels`` and the final ReLU; returns the branch width ``C / q``."""
    if len(pools) != len(dilations):
        raise ValueError("DAPPF needs one dilation per pyramid level")
    mid = channels // compression
    module.pools = tuple(pools)
    module.base = ConvBNReLU(channels, mid, 1)
    module.fuse = ConvBNReLU(mid * (len(pools) + 1), channels, 1, relu=False)
    module.relu = nn.ReLU(inplace=True)
    return mid


class DAPPF(_Pyramid):
    """Dilated Asymmetric Pooling Pyramid Fusion module (Fig. 4), the "pooled" reading (default).

    (a) Three asymmetric pooling layers, one per pyramid level, each going deeper than the one
    before: level 1 pools the input, levels 2 and 3 pool the previous level's output ("for
    deeper extraction of feature map information"). A level's pooling is the sum of a
    vertical (``k x 1``) and a horizontal (``1 x k``) average pool, both with stride ``s``
    along both axes, so the cumulative strides are 2, 4, 8 with the default (5, 2) per level,
    as in DAPPM's pyramid. (b) On every level, at the level's pooled resolution, two asymmetric
    depthwise separable convolutions, the second dilated with that level's rate (4, 8, 12);
    the level's 1x1 convolutions carry biases and no batch norm (their maps have a few pixels).
    (c) The branches carry ``C / q`` channels: level 1 reduces the input ``C -> C/q``, the
    deeper levels stay at ``C/q``. As in DAPPM, the branch work happens at the pooled scale and only
    the 1x1 branch and the fusion run at the input's resolution: the levels are upsampled,
    concatenated with the 1x1 branch, fused back to ``C`` by a 1x1 conv and added to the input,
    so the output has the input's size (Table III: +0.26 M, +0.04 G; here 0.257 M and 0.043 G
    on V2's 15 x 20 map).

    On FEAGNet-V1 (a 7 x 10 map at 480x640) the levels are 4 x 5, 2 x 3 and 1 x 2: the
    dilation-8 and -12 taps fall entirely into the zero padding there, so those convolutions
    act as per-channel scales; on V2 (8 x 10, 4 x 5, 2 x 3) the same holds for the dilation-8
    and -12 levels. The paper's rates are kept as printed.

    Args:
        channels: input and output channels ``C``.
        compression: ``q``, the branch compression (2 in the paper).
        pools: (kernel, stride) of each level's pooling, relative to the level before.
        dilations: dilation of each level's second separable convolution.
    """

    def __init__(
        self,
        channels: int,
        *,
        compression: int = 2,
        pools: tuple[tuple[int, int], ...] = ((5, 2), (5, 2), (5, 2)),
        dilations: tuple[int, ...] = (4, 8, 12),
    ) -> None:
        super().__init__()
        mid = _pyramid_setup(self, channels, compression, pools, dilations)
        # the levels work on maps of a few pixels (1 x 2 on V1's deepest level at 480x640): no
        # batch norm there, whose statistics over a batch of single pixels blow up the
        # gradients; the fusion at the input's resolution normalises
        self.reduce = nn.ModuleList(_conv_relu(channels if i == 0 else mid, mid)
                                    for i in range(len(pools)))
        self.process = nn.ModuleList(
            nn.Sequential(AsymmetricSeparableConv(mid, norm=False),
                          AsymmetricSeparableConv(mid, dilation=d, norm=False))
            for d in dilations)

    @staticmethod
    def _cross_pool(x: torch.Tensor, kernel: int, stride: int) -> torch.Tensor:
        """Vertical plus horizontal strip average pool, both strided along both axes (the two
        give the same output size: ceil(H / s) x ceil(W / s))."""
        pad = kernel // 2
        vertical = F.avg_pool2d(x, (kernel, 1), stride, (pad, 0), count_include_pad=False)
        horizontal = F.avg_pool2d(x, (1, kernel), stride, (0, pad), count_include_pad=False)
        return vertical + horizontal

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        size = x.shape[-2:]
        outs = [self.base(x)]
        y = x
        for (kernel, stride), reduce, process in zip(self.pools, self.reduce, self.process,
                                                     strict=True):
            y = process(reduce(self._cross_pool(y, kernel, stride)))
            outs.append(resize_to(y, size))
        return self.relu(self.fuse(torch.cat(outs, dim=1)) + x)


class DAPPFFullRes(_Pyramid):
    """DAPPF, the "fullres" reading (``dappf="fullres"``; evsmap's default before the Table III
    row fit): every level works at the input's resolution. 0.28 M parameters, 0.09 G (V2).

    (a) three pyramid levels, each pooling with a pair of asymmetric (vertical and horizontal
    strip) average pools of growing size; (b) on every level two asymmetric depthwise separable
    convolutions, the second dilated with that level's rate (4, 8, 12); (c) every branch carries
    ``C / q`` channels. As in DAPPM/PAPPM, each level also receives the previous level's output,
    a 1x1 branch keeps the unpooled map, the branches are concatenated and fused back to ``C``
    channels by a 1x1 conv, and the input is added back, so the output has the input's size.

    Args:
        channels: input and output channels ``C``.
        compression: ``q``, the branch compression (2 in the paper).
        pools: (kernel, stride) of each level's strip pools.
        dilations: dilation of each level's second separable convolution.
    """

    def __init__(
        self,
        channels: int,
        *,
        compression: int = 2,
        pools: tuple[tuple[int, int], ...] = ((5, 2), (9, 4), (17, 8)),
        dilations: tuple[int, ...] = (4, 8, 12),
    ) -> None:
        super().__init__()
        mid = _pyramid_setup(self, channels, compression, pools, dilations)
        self.reduce = nn.ModuleList(ConvBNReLU(channels, mid, 1) for _ in pools)
        self.process = nn.ModuleList(
            nn.Sequential(AsymmetricSeparableConv(mid), AsymmetricSeparableConv(mid, dilation=d))
            for d in dilations)

    @staticmethod
    def _strip_pools(x: torch.Tensor, kernel: int, stride: int) -> torch.Tensor:
        pad = kernel // 2
        vertical = F.avg_pool2d(x, (kernel, 1), (stride, 1), (pad, 0), count_include_pad=False)
        horizontal = F.avg_pool2d(x, (1, kernel), (1, stride), (0, pad), count_include_pad=False)
        size = x.shape[-2:]
        return resize_to(vertical, size) + resize_to(horizontal, size)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        outs = [self.base(x)]
        prev = outs[0]
        for (kernel, stride), reduce, process in zip(self.pools, self.reduce, self.process,
                                                     strict=True):
            prev = process(reduce(self._strip_pools(x, kernel, stride)) + prev)
            outs.append(prev)
        return self.relu(self.fuse(torch.cat(outs, dim=1)) + x)


DAPPF_READINGS = {"pooled": DAPPF, "fullres": DAPPFFullRes}
"""DAPPF readings by name (``dappf=``): the default first."""


class LBU(nn.Module):
    """Lightweight Bottleneck Unit (Fig. 5), after DABNet's DAB / FASSD-Net's MDA module.

    BN-PReLU, a 3x3 conv halving the channels, two parallel depthwise asymmetric branches
    (3x1 + 1x3, and the same dilated), summed, BN-PReLU, a 1x1 conv restoring the channels
    (the cross-channel step), and a residual connection.

    Args:
        channels: input and output channels.
        dilation: dilation of the second branch.
    """

    def __init__(self, channels: int, *, dilation: int = 2) -> None:
        super().__init__()
        half = channels // 2
        self.pre = nn.Sequential(nn.BatchNorm2d(channels), nn.PReLU(channels))
        self.reduce = nn.Conv2d(channels, half, 3, padding=1, bias=False)

        def branch(d: int) -> nn.Sequential:
            return nn.Sequential(
                nn.Conv2d(half, half, (3, 1), padding=(d, 0), dilation=(d, 1), groups=half,
                          bias=False),
                nn.Conv2d(half, half, (1, 3), padding=(0, d), dilation=(1, d), groups=half,
                          bias=False),
            )

        self.local = branch(1)
        self.context = branch(dilation)
        self.post = nn.Sequential(nn.BatchNorm2d(half), nn.PReLU(half))
        self.expand = nn.Conv2d(half, channels, 1, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.reduce(self.pre(x))
        y = self.post(self.local(y) + self.context(y))
        return x + self.expand(y)


class AxisAttention(nn.Module):
    """Height-direction (HA) and width-direction (WA) attention (Fig. 5).

    Shared 1x1 query/key projections (``C -> C/key_reduction``) give, for every column, an
    ``H x H`` affinity matrix (HA) and, for every row, a ``W x W`` one (WA): the co-attention
    affinities of the two directions, each softmax-normalised on its own. They aggregate one
    shared 1x1 value projection (``values=1``, CCNet's criss-cross layout, keys at ``C/8``) or
    one per direction (``values=2``); the two results are summed and added to the input with a
    learned scale initialised to 0 (CCNet/DANet).

    Args:
        channels: feature channels ``C``.
        key_reduction: ``C`` divided by the query/key width.
        values: 1 (shared by both directions) or 2 (one per direction) value projections.
    """

    def __init__(self, channels: int, *, key_reduction: int = 8, values: int = 1) -> None:
        super().__init__()
        if values not in (1, 2):
            raise ValueError(f"AxisAttention takes 1 or 2 value projections, got {values}")
        keys = max(channels // key_reduction, 1)
        self.query = nn.Conv2d(channels, keys, 1)
        self.key = nn.Conv2d(channels, keys, 1)
        self.value_h = nn.Conv2d(channels, channels, 1)
        self.value_w = nn.Conv2d(channels, channels, 1) if values == 2 else None
        self.gamma = nn.Parameter(torch.zeros(1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        q, k = self.query(x), self.key(x)
        v_h = self.value_h(x)
        v_w = v_h if self.value_w is None else self.value_w(x)
        # height direction: one H x H affinity per column (batched over b, w)
        q_h, k_h = q.permute(0, 3, 2, 1), k.permute(0, 3, 1, 2)  # (b, w, h, c'), (b, w, c', h)
        aff_h = torch.softmax(torch.matmul(q_h, k_h), dim=-1)  # (b, w, h, h)
        out_h = torch.matmul(aff_h, v_h.permute(0, 3, 2, 1))  # (b, w, h, c)
        # width direction: one W x W affinity per row (batched over b, h)
        q_w, k_w = q.permute(0, 2, 3, 1), k.permute(0, 2, 1, 3)  # (b, h, w, c'), (b, h, c', w)
        aff_w = torch.softmax(torch.matmul(q_w, k_w), dim=-1)  # (b, h, w, w)
        out_w = torch.matmul(aff_w, v_w.permute(0, 2, 3, 1))  # (b, h, w, c)
        return x + self.gamma * (out_h.permute(0, 3, 2, 1) + out_w.permute(0, 3, 1, 2))


ATTENTION_READINGS: dict[str, dict] = {
    "merged": dict(key_reduction=8, values=1),
    "lbu": dict(key_reduction=4, values=2),
}
"""HA/WA readings by name (``attention=``), the default first: where in each LAD stage the
attention runs and its projections. ``merged``: on the stage's output, after the skip is
merged at the higher resolution, CCNet's projections (keys C/8, one value). ``lbu``: after the
three LBUs at the stage's input resolution, keys C/4 and one value per direction (evsmap's
default before the Table III row fit)."""


class LADStage(nn.Module):
    """One stage of the Lightweight Attention Decoder: three LBUs at the stage's input
    resolution, then x2 (bilinear) upsampling to the encoder skip's size, the skip merged in
    (concatenation, 1x1 conv-BN-ReLU), and HA/WA attention on the merged map; the result feeds
    the next stage. With ``attention_site="lbu"`` the attention runs after the LBUs, before
    the upsampling, instead.

    Args:
        in_channels: channels coming from the deeper stage.
        skip_channels: channels of the encoder skip.
        out_channels: channels of this stage.
        units: number of LBUs (three in the paper).
        dilations: dilation of each LBU's context branch.
        attention: the HA/WA reading (:data:`ATTENTION_READINGS`), or ``None`` for none
            (Table III's rows without "WA&HA").
    """

    def __init__(self, in_channels: int, skip_channels: int, out_channels: int, *,
                 units: int = 3, dilations: tuple[int, ...] = (2, 4, 8),
                 attention: str | None = "merged") -> None:
        super().__init__()
        if len(dilations) != units:
            raise ValueError("LADStage needs one dilation per LBU")
        if attention is not None and attention not in ATTENTION_READINGS:
            raise ValueError(f"unknown attention reading {attention!r} (known: "
                             f"{', '.join(ATTENTION_READINGS)})")
        self.units = nn.Sequential(*(LBU(in_channels, dilation=d) for d in dilations))
        self.site = attention
        self.merge = ConvBNReLU(in_channels + skip_channels, out_channels, 1)
        if attention is None:
            self.attention: nn.Module = nn.Identity()
        else:
            width = in_channels if attention == "lbu" else out_channels
            self.attention = AxisAttention(width, **ATTENTION_READINGS[attention])

    def forward(self, x: torch.Tensor, skip: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Returns (stage features before upsampling, merged output for the next stage)."""
        x = self.units(x)
        if self.site == "lbu":
            x = self.attention(x)
        out = self.merge(torch.cat([resize_to(x, skip.shape[-2:]), skip], dim=1))
        if self.site not in (None, "lbu"):
            out = self.attention(out)
        return x, out


# ---------------------------------------------------------------------------------------------
# model


class FEAGNet(StridedLogits, nn.Module):
    """FEAGNet: RGB-D (or RGB-only) semantic segmentation.

    In eval mode ``forward`` returns logits at the input resolution (at the output stride, 4
    for V2 and 8 for V1, while :attr:`~evsmap.models.layers.StridedLogits.upsample_logits` is
    off); in training mode with
    ``multiscale=True`` it returns ``(main, side, side)``: the main logits, then the side heads
    of the second and first decoder stages (1/8 and 1/16 of the input for V2, 1/16 and 1/32 for
    V1), for multi-scale supervision.

    Args:
        num_classes: number of output classes.
        use_depth: two encoders (RGB-D, V1/V2) or the RGB encoder only (S/L).
        init_strides: strides of the four init-layer convs; V2 uses FC-HarDNet's (2, 1, 2, 1),
            V1 strides the second conv too, (2, 2, 2, 1), so every later layer sees a quarter of
            the pixels.
        growth: HarDBlock growth rate per encoder stage.
        layers: HarDBlock layer count per encoder stage.
        transitions: encoder transition widths (stage output channels).
        decoder_channels: channels of the three LAD stages, deepest first.
        cfim: fuse the modalities with CFIM (``True``: the default reading, or a name of
            :data:`CFIM_READINGS`; ``False``: element-wise addition, the baseline).
        cfim_reduction: ``v`` of the CFIM's fully connected layers (None: the reading's own
            default).
        dappf: apply DAPPF to the last encoder output (``True``: the default reading, or a
            name of :data:`DAPPF_READINGS`).
        attention: HA and WA in every decoder stage (``True``: the default reading, or a name
            of :data:`ATTENTION_READINGS`).
        multiscale: add the training-only 1x1 supervision heads on the first two decoder
            stages.
    """

    def __init__(
        self,
        *,
        num_classes: int = 40,
        use_depth: bool = True,
        init_strides: tuple[int, int, int, int] = (2, 1, 2, 1),
        growth: tuple[int, ...] = (10, 16, 18, 24),
        layers: tuple[int, ...] = (4, 4, 8, 8),
        transitions: tuple[int, ...] = (64, 96, 160, 224),
        decoder_channels: tuple[int, int, int] = (128, 116, 64),
        cfim: bool | str = True,
        cfim_reduction: int | None = None,
        dappf: bool | str = True,
        attention: bool | str = True,
        multiscale: bool = True,
    ) -> None:
        super().__init__()
        if num_classes < 1:
            raise ValueError(f"num_classes must be positive, got {num_classes}")
        cfim_name = _reading("cfim", cfim, CFIM_READINGS)
        dappf_name = _reading("dappf", dappf, DAPPF_READINGS)
        attention_name = _reading("attention", attention, ATTENTION_READINGS)
        self.readings = {"cfim": cfim_name, "dappf": dappf_name, "attention": attention_name}
        self.num_classes = num_classes
        self.use_depth = use_depth
        enc: dict[str, Any] = dict(stem_strides=init_strides, growth=growth, layers=layers,
                   transitions=transitions)
        self.rgb_encoder = HarDNetEncoder(in_channels=3, **enc)
        self.depth_encoder = HarDNetEncoder(in_channels=1, **enc) if use_depth else None
        stage_channels = [self.rgb_encoder.stem_channels, *transitions]
        if use_depth and cfim_name is not None:
            extra = {} if cfim_reduction is None else {"reduction": cfim_reduction}
            self.fusion: nn.ModuleList | None = nn.ModuleList(
                CFIM_READINGS[cfim_name](c, **extra) for c in stage_channels)
        else:
            self.fusion = None
        deepest = transitions[-1]
        self.context = (DAPPF_READINGS[dappf_name](deepest) if dappf_name is not None
                        else nn.Identity())
        skips = list(reversed(transitions[:-1]))[:3]
        if len(skips) != 3:
            raise ValueError("FEAGNet needs at least four encoder stages after the init layer")
        self.decoder = nn.ModuleList()
        ch = deepest
        for skip, out in zip(skips, decoder_channels, strict=True):
            self.decoder.append(LADStage(ch, skip, out, attention=attention_name))
            ch = out
        self.head = nn.Conv2d(ch, num_classes, 1)
        stage_inputs = [deepest, *decoder_channels[:2]]
        self.side_heads = (nn.ModuleList(nn.Conv2d(c, num_classes, 1) for c in stage_inputs[1:])
                           if multiscale else None)

    def _fuse(self, index: int, rgb: torch.Tensor, depth: torch.Tensor | None
              ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(RGB stream, depth stream) after stage ``index``'s fusion."""
        if depth is None:
            return rgb, None
        if self.fusion is None:
            return rgb + depth, depth
        return self.fusion[index](rgb, depth)

    def forward(self, rgb: torch.Tensor, depth: torch.Tensor | None = None
                ) -> torch.Tensor | tuple[torch.Tensor, ...]:
        if self.use_depth and depth is None:
            raise ValueError("this FEAGNet is RGB-D: forward(rgb, depth) needs the depth image")
        size = rgb.shape[-2:]
        r = self.rgb_encoder.run_stem(rgb)
        depth_encoder = self.depth_encoder  # None unless use_depth
        d = None
        if self.use_depth:
            assert depth_encoder is not None and depth is not None
            d = depth_encoder.run_stem(depth)
        r, d = self._fuse(0, r, d)
        features = []
        for i in range(len(self.rgb_encoder.blocks)):
            _, r = self.rgb_encoder.run_block(i, r)
            if d is not None:
                assert depth_encoder is not None
                _, d = depth_encoder.run_block(i, d)
            r, d = self._fuse(i + 1, r, d)
            features.append(r)
        x = self.context(features[-1])
        stage_outputs = []
        for stage, skip in zip(self.decoder, reversed(features[-4:-1]), strict=True):
            inner, x = stage(x, skip)
            stage_outputs.append(inner)
        main = self.final_resize(self.head(x), size)
        if self.training and self.side_heads is not None:
            sides = [head(out) for head, out in zip(self.side_heads, stage_outputs[1:],
                                                    strict=True)]
            return (main, *reversed(sides))
        return main


def _reading(module: str, choice: bool | str, readings: dict) -> str | None:
    """The reading name a switch selects: ``False`` none, ``True`` the default (first)."""
    if choice is False:
        return None
    if choice is True:
        return next(iter(readings))
    if choice not in readings:
        raise ValueError(f"{module}={choice!r}: unknown reading (known: true, false, "
                         f"{', '.join(readings)})")
    return str(choice)


# ---------------------------------------------------------------------------------------------
# variants

V2_INIT_STRIDES = (2, 1, 2, 1)
"""FC-HarDNet-70's init layer: the encoders start at 1/4 resolution."""
V1_INIT_STRIDES = (2, 2, 2, 1)
"""V1 strides the init layer's second conv too: the encoders start at 1/8 resolution."""

ABLATIONS: dict[str, dict[str, bool]] = {
    "basel": dict(cfim=False, dappf=False, attention=False, multiscale=False),
    "basel+cfim": dict(cfim=True, dappf=False, attention=False, multiscale=False),
    "basel+dappf": dict(cfim=False, dappf=True, attention=False, multiscale=False),
    "basel+cfim+dappf": dict(cfim=True, dappf=True, attention=False, multiscale=False),
    "basel+cfim+dappf+waha": dict(cfim=True, dappf=True, attention=True, multiscale=False),
    "full": dict(cfim=True, dappf=True, attention=True, multiscale=True),
}
"""The six rows of Table III (ablation on NYUv2, FEAGNet-V2), top to bottom."""


def feagnet_v1(*, num_classes: int = 40, **switches: Any) -> FEAGNet:
    """FEAGNet-V1: RGB-D, strided init layer (Table I: 4.5 M, 1.9 G at 480x640)."""
    return FEAGNet(num_classes=num_classes, init_strides=V1_INIT_STRIDES, **switches)


def feagnet_v2(*, num_classes: int = 40, **switches: Any) -> FEAGNet:
    """FEAGNet-V2: RGB-D, FC-HarDNet's init layer (Table I: 4.5 M, 7.8 G at 480x640)."""
    return FEAGNet(num_classes=num_classes, init_strides=V2_INIT_STRIDES, **switches)


def feagnet_s(*, num_classes: int = 19, **switches: Any) -> FEAGNet:
    """FEAGNet-S: RGB only, strided init layer (Table II: 2.8 M, Cityscapes)."""
    return FEAGNet(num_classes=num_classes, use_depth=False, init_strides=V1_INIT_STRIDES,
                   **switches)


def feagnet_l(*, num_classes: int = 19, **switches: Any) -> FEAGNet:
    """FEAGNet-L: RGB only, FC-HarDNet's init layer (Table II: 2.8 M, Cityscapes)."""
    return FEAGNet(num_classes=num_classes, use_depth=False, init_strides=V2_INIT_STRIDES,
                   **switches)
