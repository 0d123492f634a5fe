"""FEAGNet's blocks (Section III-A, Fig. 3-5): the Cross-Modal Feature Interaction Module (CFIM),
the Dilated Asymmetric Pooling Pyramid Fusion module (DAPPF), the Lightweight Bottleneck Unit
(LBU), the height- and width-direction attention (HA/WA) and the stage of the Lightweight
Attention Decoder (LAD) that holds them; :mod:`evsmap.models.feagnet` assembles them into the
network. Each block has the reading that fits its own Table III row by default and the earlier
readings as named options (:data:`CFIM_READINGS`, :data:`DAPPF_READINGS`,
:data:`ATTENTION_READINGS`); ``docs/feagnet.md`` says why each reading is what it is."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from evsmap.models.layers import ConvBNReLU, resize_to


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
