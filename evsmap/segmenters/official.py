"""Official released checkpoints of the baseline networks, renamed to evsmap's module names.

A weights file is recognised by its key names (:func:`detect_layout`):

``esanet-release``
    TUI-NICR/ESANet's released ESANet-R34-NBt1D files (``{'state_dict': ...}``, keys
    ``encoder_rgb.*``, ``encoder_depth.*``, ``se_layer0..4.*``, ``skip_layer1..3.*``,
    ``context_module.*``, ``decoder.*``). The configuration follows from the file: the classes
    from the output channels of ``decoder.conv_out``, the context module from the pyramid
    branches (``ppm``: each branch is ``Sequential(AdaptiveAvgPool2d, ConvBNAct)``, so its keys
    read ``features.<i>.1.conv``; ``appm``: ``features.<i>.conv``; 2 branches for bins (1, 5),
    4 for (1, 2, 4, 8)). Released: NYUv2 (40 classes, ``ppm``, 898 tensors), SUN RGB-D (37,
    ``ppm``, 898) and Cityscapes (19, ``appm-1-2-4-8``, 910).
``fchardnet-release``
    PingoLH/FCHarDNet's released ``hardnet70_cityscapes_model.pkl`` (``{'epoch',
    'model_state', 'best_iou'}``, keys ``module.base.*``, ``module.conv1x1_up.*``,
    ``module.denseBlocksUp.*``, ``module.finalConv.*``: 416 tensors at 19 classes; the
    ``module.`` prefix of DataParallel is removed before the layout is detected). The official
    model reads **BGR** images normalised with the ImageNet mean/std in BGR order
    (``ptsemseg/loader/cityscapes_loader.py``, ``test.py``); evsmap feeds RGB normalised with
    the same statistics in RGB order, i.e. the same tensor with its channels reversed. The
    conversion therefore reverses the input channels of the first convolution, and the
    converted network gives the official output on evsmap's RGB input.
``evsmap``
    a file written by ``evsmap weights convert``: ``{'state_dict': ..., 'card': {...}}`` with
    evsmap's key names (see :mod:`evsmap.segmenters.cards` for the card).
``plain``
    any other state dict, loaded as it is.

The key tables are data: :func:`esanet_table` and :func:`fchardnet_table` map each official
module that holds tensors to evsmap's module (the tensor names inside a module - ``weight``,
``bias``, ``running_mean``, ``running_var``, ``num_batches_tracked`` - are the same on both
sides), built from the per-module tables below and the networks' block counts; the converter
(:func:`convert_state`) only looks keys up in them. Nothing here imports torch.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from evsmap.errors import DataFormatError

ESANET = "esanet-release"
FCHARDNET = "fchardnet-release"
EVSMAP = "evsmap"
PLAIN = "plain"

LAYOUTS: dict[str, str] = {
    ESANET: "official ESANet release (TUI-NICR/ESANet, ESANet-R34-NBt1D)",
    FCHARDNET: "official FC-HarDNet release (PingoLH/FCHarDNet, FC-HarDNet-70)",
    EVSMAP: "evsmap checkpoint with a card (evsmap weights convert)",
    PLAIN: "plain state dict",
}
"""Layout name -> description."""

_SHOW = 8

# --------------------------------------------------------------------------------------------
# ESANet (src/models/model.py, resnet.py, rgb_depth_fusion.py, model_utils.py,
# context_modules.py of TUI-NICR/ESANet) -> baselines/esanet.py
# --------------------------------------------------------------------------------------------

ESANET_NBT1D: tuple[tuple[str, str], ...] = (
    ("conv3x1_1", "conv_v1"),
    ("conv1x3_1", "conv_h1"),
    ("bn1", "bn1"),
    ("conv3x1_2", "conv_v2"),
    ("conv1x3_2", "conv_h2"),
    ("bn2", "bn2"),
)
"""``NonBottleneck1D`` (official) -> ``NonBottleneck1D`` (evsmap)."""

ESANET_DOWNSAMPLE: tuple[tuple[str, str], ...] = (
    ("downsample.0", "shortcut.0"),  # 1x1 conv
    ("downsample.1", "shortcut.1"),  # BN
)
"""The strided shortcut of the first block of encoder stages 2-4."""

ESANET_CONV_BN_ACT: tuple[tuple[str, str], ...] = (("conv", "0"), ("bn", "1"))
"""``ConvBNAct`` (named children conv, bn, act) -> ``Sequential(Conv2d, BatchNorm2d, ReLU)``."""

ESANET_SE: tuple[tuple[str, str], ...] = (("fc.0", "squeeze"), ("fc.2", "excite"))
"""``SqueezeAndExcitation.fc = Sequential(conv, act, conv, sigmoid)`` -> ``SqueezeExcite``."""

ESANET_FIXED: tuple[tuple[str, str], ...] = (
    ("decoder.conv_out", "classifier"),
    ("decoder.upsample1.conv", "upsample.0.conv"),
    ("decoder.upsample2.conv", "upsample.1.conv"),
)
"""Single modules of the decoder head."""

ESANET_STAGE_BLOCKS: tuple[int, ...] = (3, 4, 6, 3)
"""Blocks per encoder stage (ResNet-34), official ``layer1..4`` -> evsmap ``stages.0..3``."""

ESANET_FUSIONS = 5
"""``se_layer0..4`` -> ``fusions.0..4`` (after the stem and after each stage)."""

ESANET_SKIPS = 3
"""``skip_layer1..3`` (1/4, 1/8, 1/16) -> ``skips.0..2``."""

ESANET_DECODER_MODULES = 3
"""``decoder.decoder_module_1..3`` -> ``decoder.0..2``."""

ESANET_DECODER_BLOCKS = 3
"""Non-bottleneck-1D blocks per decoder module (``--nr_decoder_blocks 3``)."""

ESANET_RELEASES: dict[str, tuple[str, int]] = {
    "nyuv2": ("ppm", 40),
    "sunrgbd": ("ppm", 37),
    "cityscapes": ("appm-1-2-4-8", 19),
}
"""Released configurations: dataset -> (context module, classes)."""

ESANET_CONTEXTS: dict[tuple[bool, int], str] = {
    (True, 2): "ppm",
    (True, 4): "ppm-1-2-4-8",
    (False, 2): "appm",
    (False, 4): "appm-1-2-4-8",
}
"""(branches pool inside a Sequential, number of branches) -> context module name."""

_ESANET_DATASET_OF_CONTEXT = {"ppm": "nyuv2", "appm-1-2-4-8": "cityscapes"}
"""The ``dataset`` option of ``esanet-r34-nbt1d`` that builds each context module."""

# --------------------------------------------------------------------------------------------
# FC-HarDNet (ptsemseg/models/hardnet.py of PingoLH/FCHarDNet) -> baselines/fchardnet.py
# --------------------------------------------------------------------------------------------

FCHARDNET_CONV_LAYER: tuple[tuple[str, str], ...] = (("conv", "0"), ("norm", "1"))
"""``ConvLayer`` (named children conv, norm, relu) -> ``ConvBNReLU`` (a Sequential)."""

FCHARDNET_STEM = 4
"""``base.0..3``: the four stem ConvLayers -> ``encoder.stem.0..3``."""

FCHARDNET_BLOCK_LAYERS: tuple[int, ...] = (4, 4, 8, 8, 8)
"""Layers of the encoder HarDBlocks. In the official ``base`` list each block is followed by
its 1x1 transition ConvLayer and, but for the last, a parameter-free AvgPool2d: blocks at
``base.4, 7, 10, 13, 16``, transitions at ``base.5, 8, 11, 14, 17``. The decoder blocks
(``denseBlocksUp.0..3``) reuse the layer counts of encoder blocks 3, 2, 1, 0."""

FCHARDNET_FIXED: tuple[tuple[str, str], ...] = (("finalConv", "head"),)

FCHARDNET_BGR_KEY = "base.0.conv.weight"
"""The official tensor whose input channels are ordered B, G, R (reversed by the conversion)."""

FCHARDNET_DATASETS: dict[int, str] = {19: "cityscapes", 40: "nyuv2", 37: "sunrgbd"}
"""Classes -> the ``dataset`` option of ``fchardnet-70`` (size and class names)."""


def _under(pairs: Iterable[tuple[str, str]], official: str, ours: str) -> list[tuple[str, str]]:
    return [(f"{official}.{a}", f"{ours}.{b}") for a, b in pairs]


def _table(rows: list[tuple[str, str]]) -> dict[str, str]:
    table = dict(rows)
    if len(table) != len(rows) or len(set(table.values())) != len(rows):
        raise AssertionError("a key table maps two modules onto one")  # a bug in the tables
    return table


def esanet_table(context: str = "ppm") -> dict[str, str]:
    """Official ESANet-R34-NBt1D module path -> evsmap module path, for every module that holds
    tensors, with the context module ``context`` (one of :data:`ESANET_CONTEXTS`' values)."""
    pooled, branches = next(k for k, v in ESANET_CONTEXTS.items() if v == context)
    rows: list[tuple[str, str]] = []
    for modality in ("rgb", "depth"):
        enc = f"encoder_{modality}"
        rows += [(f"{enc}.conv1", f"{enc}.stem.0"), (f"{enc}.bn1", f"{enc}.stem.1")]
        for stage, blocks in enumerate(ESANET_STAGE_BLOCKS):
            for block in range(blocks):
                official, ours = f"{enc}.layer{stage + 1}.{block}", f"{enc}.stages.{stage}.{block}"
                rows += _under(ESANET_NBT1D, official, ours)
                if block == 0 and stage > 0:
                    rows += _under(ESANET_DOWNSAMPLE, official, ours)
    for k in range(ESANET_FUSIONS):
        for modality in ("rgb", "depth"):
            rows += _under(ESANET_SE, f"se_layer{k}.se_{modality}", f"fusions.{k}.se_{modality}")
    for k in range(ESANET_SKIPS):
        rows += _under(ESANET_CONV_BN_ACT, f"skip_layer{k + 1}.0", f"skips.{k}")
    for k in range(branches):
        official = f"context_module.features.{k}" + (".1" if pooled else "")
        rows += _under(ESANET_CONV_BN_ACT, official, f"context.branches.{k}")
    rows += _under(ESANET_CONV_BN_ACT, "context_module.final_conv", "context.fuse")
    for k in range(ESANET_DECODER_MODULES):
        official, ours = f"decoder.decoder_module_{k + 1}", f"decoder.{k}"
        rows += _under(ESANET_CONV_BN_ACT, f"{official}.conv3x3", f"{ours}.conv")
        for block in range(ESANET_DECODER_BLOCKS):
            rows += _under(ESANET_NBT1D, f"{official}.decoder_blocks.{block}",
                           f"{ours}.blocks.{block}")
        rows += [(f"{official}.upsample.conv", f"{ours}.upsample.conv"),
                 (f"{official}.side_output", f"{ours}.side_output")]
    rows += ESANET_FIXED
    return _table(rows)


def fchardnet_table() -> dict[str, str]:
    """Official FC-HarDNet-70 module path -> evsmap module path, for every module that holds
    tensors."""
    rows: list[tuple[str, str]] = []
    for k in range(FCHARDNET_STEM):
        rows += _under(FCHARDNET_CONV_LAYER, f"base.{k}", f"encoder.stem.{k}")
    index = FCHARDNET_STEM
    last = len(FCHARDNET_BLOCK_LAYERS) - 1
    for block, layers in enumerate(FCHARDNET_BLOCK_LAYERS):
        for layer in range(layers):
            rows += _under(FCHARDNET_CONV_LAYER, f"base.{index}.layers.{layer}",
                           f"encoder.blocks.{block}.layers.{layer}")
        rows += _under(FCHARDNET_CONV_LAYER, f"base.{index + 1}", f"encoder.transitions.{block}")
        index += 2 if block == last else 3  # block, transition (, pool)
    for k in range(last):
        rows += _under(FCHARDNET_CONV_LAYER, f"conv1x1_up.{k}", f"reduce.{k}")
        for layer in range(FCHARDNET_BLOCK_LAYERS[last - 1 - k]):
            rows += _under(FCHARDNET_CONV_LAYER, f"denseBlocksUp.{k}.layers.{layer}",
                           f"up_blocks.{k}.layers.{layer}")
    rows += FCHARDNET_FIXED
    return _table(rows)


# --------------------------------------------------------------------------------------------
# detection and conversion
# --------------------------------------------------------------------------------------------


def detect_layout(keys: Iterable[str], card: Mapping[str, Any] | None = None) -> str:
    """The layout of a state dict with ``keys`` (``module.`` prefix already removed)."""
    keys = set(keys)
    if {"encoder_rgb.conv1.weight", "decoder.conv_out.weight"} <= keys:
        return ESANET
    if {FCHARDNET_BGR_KEY, "finalConv.weight"} <= keys:
        return FCHARDNET
    return EVSMAP if card is not None else PLAIN


@dataclass
class Converted:
    """A state dict in evsmap's key names and what it was converted from.

    Attributes:
        state: the tensors under evsmap's names.
        layout: the source layout (a key of :data:`LAYOUTS`).
        network: class name of the evsmap network the layout is for (``ESANet``,
            ``FCHarDNet``), None for evsmap's own and plain files.
        segmenter: the registered segmenter it is for, where known.
        num_classes: classes of the classifier, where known.
        context: ESANet's context module.
        dataset: the released configuration (``nyuv2``, ``sunrgbd``, ``cityscapes``), or None.
        options: segmenter options that build a network this file fits (None: none does).
        notes: what the conversion did besides renaming.
        official_names: evsmap key -> the file's key, for renamed keys.
        card: the card of an evsmap checkpoint.
    """

    state: dict[str, Any]
    layout: str
    network: str | None = None
    segmenter: str | None = None
    num_classes: int | None = None
    context: str | None = None
    dataset: str | None = None
    options: dict[str, Any] | None = None
    notes: list[str] = field(default_factory=list)
    official_names: dict[str, str] = field(default_factory=dict)
    card: dict[str, Any] | None = None

    def describe(self) -> str:
        """One phrase, e.g. ``official ESANet release (...) in the cityscapes configuration
        (19 classes, context appm-1-2-4-8)``."""
        text = LAYOUTS[self.layout]
        if self.layout == ESANET:
            which = f"the {self.dataset}" if self.dataset else "a custom"
            return (f"{text} in {which} configuration ({self.num_classes} classes, context "
                    f"{self.context})")
        if self.layout == FCHARDNET:
            return f"{text} with {self.num_classes} classes (BGR input)"
        if self.layout == EVSMAP and self.card:
            options = ", ".join(f"{k}={v}" for k, v in (self.card.get("options") or {}).items())
            return f"{text} for {self.card.get('model')}" + (f" ({options})" if options else "")
        return text


def _listing(names: list[str]) -> str:
    more = f" and {len(names) - _SHOW} more" if len(names) > _SHOW else ""
    return ", ".join(names[:_SHOW]) + more


def _shape(state: Mapping[str, Any], key: str, source: str, what: str) -> tuple[int, ...]:
    if key not in state:
        raise DataFormatError(f"{source}: {what} without {key}")
    return tuple(state[key].shape)


def _esanet_context(keys: set[str], source: str) -> str:
    branches = {int(m.group(1)) for k in keys
                if (m := re.match(r"context_module\.features\.(\d+)\.", k))}
    pooled = any(k.startswith("context_module.features.0.1.") for k in keys)
    context = ESANET_CONTEXTS.get((pooled, len(branches)))
    if context is None:
        raise DataFormatError(
            f"{source}: {LAYOUTS[ESANET]} with an unsupported context module "
            f"({len(branches)} pyramid branches; evsmap builds ppm/appm with 2 or 4)")
    return context


def _rename(state: Mapping[str, Any], table: Mapping[str, str], source: str,
            what: str) -> tuple[dict[str, Any], dict[str, str]]:
    renamed: dict[str, Any] = {}
    names: dict[str, str] = {}
    unmapped = []
    for key, tensor in state.items():
        module, _, leaf = key.rpartition(".")
        target = table.get(module)
        if target is None:
            unmapped.append(key)
            continue
        renamed[f"{target}.{leaf}"] = tensor
        names[f"{target}.{leaf}"] = key
    if unmapped:
        raise DataFormatError(
            f"{source}: {what}: {len(unmapped)} of {len(state)} keys have no evsmap name "
            f"(first: {_listing(unmapped)})")
    return renamed, names


def _fill_batch_counts(state: dict[str, Any], notes: list[str]) -> None:
    """BatchNorms saved by PyTorch < 0.4.1 have no ``num_batches_tracked`` (unused in eval)."""
    missing = [k[: -len("running_mean")] + "num_batches_tracked" for k in state
               if k.endswith(".running_mean")]
    missing = [k for k in missing if k not in state]
    if missing:
        import torch

        for key in missing:
            state[key] = torch.zeros((), dtype=torch.long)
        notes.append(f"{len(missing)} BatchNorm num_batches_tracked counters absent, set to 0")


def convert_state(state: Mapping[str, Any], *, source: str = "state dict",
                  card: Mapping[str, Any] | None = None) -> Converted:
    """Recognise the layout of ``state`` and rename it to evsmap's keys.

    Args:
        state: tensors by name (a DataParallel ``module.`` prefix already removed).
        source: the file, for messages.
        card: the ``card`` stored next to the state dict, if any.

    Raises:
        DataFormatError: an official layout with keys the tables do not map (a variant evsmap
            does not build, e.g. ESANet with a ResNet-18 or BasicBlock encoder), or without the
            tensors that tell its configuration.
    """
    keys = set(state)
    layout = detect_layout(keys, card)
    if layout == ESANET:
        num_classes = _shape(state, "decoder.conv_out.weight", source, LAYOUTS[ESANET])[0]
        context = _esanet_context(keys, source)
        dataset = next((d for d, cfg in ESANET_RELEASES.items()
                        if cfg == (context, num_classes)), None)
        options: dict[str, Any] | None
        if dataset is not None:
            options = {"dataset": dataset}
        elif context in _ESANET_DATASET_OF_CONTEXT:
            options = {"dataset": _ESANET_DATASET_OF_CONTEXT[context], "num_classes": num_classes}
        else:
            options = None
        what = f"{LAYOUTS[ESANET]} ({num_classes} classes, context {context})"
        renamed, names = _rename(state, esanet_table(context), source, what)
        out = Converted(state=renamed, layout=layout, network="ESANet",
                        segmenter="esanet-r34-nbt1d", num_classes=num_classes, context=context,
                        dataset=dataset, options=options, official_names=names)
    elif layout == FCHARDNET:
        num_classes = _shape(state, "finalConv.weight", source, LAYOUTS[FCHARDNET])[0]
        first = _shape(state, FCHARDNET_BGR_KEY, source, LAYOUTS[FCHARDNET])
        what = f"{LAYOUTS[FCHARDNET]} ({num_classes} classes)"
        if len(first) != 4 or first[1] != 3:
            raise DataFormatError(f"{source}: {what}: {FCHARDNET_BGR_KEY} has shape {first}, "
                                  f"expected (16, 3, 3, 3)")
        renamed, names = _rename(state, fchardnet_table(), source, what)
        first_key = next(k for k, v in names.items() if v == FCHARDNET_BGR_KEY)
        renamed[first_key] = renamed[first_key].flip(1)
        dataset = FCHARDNET_DATASETS.get(num_classes)
        out = Converted(state=renamed, layout=layout, network="FCHarDNet",
                        segmenter="fchardnet-70", num_classes=num_classes,
                        dataset=dataset if num_classes == 19 else None,
                        options={"dataset": dataset} if dataset else {"num_classes": num_classes},
                        notes=[f"input channels of {first_key} reversed: the official model "
                               f"reads BGR, evsmap feeds RGB (same ImageNet mean/std per "
                               f"colour)"],
                        official_names=names)
    else:
        return Converted(state=dict(state), layout=layout,
                         card=dict(card) if card is not None else None,
                         segmenter=(card or {}).get("model"),
                         options=(card or {}).get("options"))
    _fill_batch_counts(out.state, out.notes)
    return out


def check_fits(converted: Converted, module: Any, source: str) -> None:
    """Refuse, in one clear sentence, an official checkpoint for another network or another
    configuration than ``module``'s (classes; ESANet's context module).

    Raises:
        DataFormatError: naming the file's configuration, the network's and the segmenter
            options that would fit.
    """
    if converted.network is None:
        return
    have = type(module).__name__
    what = converted.describe()
    if have != converted.network:
        raise DataFormatError(
            f"{source}: the file is the {what}, for {converted.segmenter} "
            f"({converted.network}), not {have}")
    classes = getattr(module, "num_classes", None)
    context = getattr(module, "context_name", None)
    mismatch = classes is not None and classes != converted.num_classes
    if converted.context is not None and context is not None:
        mismatch = mismatch or context != converted.context
    if not mismatch:
        return
    net = f"{classes} classes" + (f", context {context}" if context is not None else "")
    if converted.options is None:
        hint = f"no {converted.segmenter} option builds context {converted.context}"
    else:
        opts = " ".join(f"-o {k}={v}" for k, v in converted.options.items())
        call = ", ".join(f"{k}={v!r}" for k, v in converted.options.items())
        gives = f"{converted.num_classes} classes" + (
            f" and context {converted.context}" if converted.context else "")
        hint = f"create {converted.segmenter} with {opts} ({call} in Python), which gives {gives}"
    raise DataFormatError(
        f"{source}: the file is the {what}, which does not fit this {have} ({net}): {hint}")
