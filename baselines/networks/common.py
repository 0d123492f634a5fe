"""Registering a comparison network: its model cards (one per label set it is trained on) and
its segmenter factory, in one call.

A network module describes its network once::

    register_network(
        "dabnet", build="baselines.networks.dabnet:dabnet",
        description="DABNet (Li et al. 2019): real-time RGB network of Table II",
        citation="Li et al., 'DABNet: Depth-wise Asymmetric Bottleneck ...', BMVC 2019",
        datasets={"cityscapes": DatasetSetting(input_size=(1024, 2048), published=(
            ("params", "table2/dabnet/params"), ("fps", "table2/dabnet/fps_2048")))},
        depth=None)

``build`` names the builder (``module:function``, imported only when a segmenter is made, so
registering imports no torch); it is called as ``builder(num_classes=N)`` (plus
``dataset=<the card's dataset>`` when it takes a ``dataset`` keyword) and returns the
``nn.Module`` whose ``forward(rgb)`` - or ``forward(rgb, depth)`` for an RGB-D network - gives
logits ``(B, C, h, w)`` (upsampled to the input or not: the segmenter resizes).

``depth`` says what an RGB-D network reads besides RGB: ``"depth"`` (one channel, metres,
standardised by the card's normalisation) or ``"hha"`` (three channels: horizontal disparity,
height above ground, angle with gravity, :mod:`baselines.hha`); ``None`` for an RGB network.
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Mapping
from dataclasses import dataclass
from os import PathLike
from typing import TYPE_CHECKING, Any

from evsmap.classes import class_names_for
from evsmap.errors import UnknownNameError
from evsmap.registry import NETWORK, SEGMENTERS
from evsmap.segmenters.model_card import (
    CLASS_SETS,
    MODEL_CARDS,
    ModelCard,
    PaperFigure,
    WeightFile,
)
from evsmap.segmenters.normalization import INDOOR, Normalization

if TYPE_CHECKING:
    from evsmap.segmenters.network import NetworkSegmenter

RGB_ONLY = Normalization(depth_mean=0.0, depth_std=1.0)
"""ImageNet RGB statistics; no depth."""

DEPTH_INPUTS = (None, "depth", "hha")

_CLASSES = {"nyuv2": ("nyuv2-40", 40), "sunrgbd": ("sunrgbd-37", 37),
            "cityscapes": ("cityscapes-19", 19)}


@dataclass(frozen=True, kw_only=True)
class DatasetSetting:
    """A network as trained on one dataset.

    Args:
        input_size: ``(height, width)`` the paper's table measures it at.
        num_classes: its classifier's classes (default: the dataset's label set; e.g. 41 for
            PGDENet's NYUv2 head that keeps the void class).
        published: ``(quantity, "table/row/column")`` references to the paper's cells.
        weights: known weight files.
        normalization: the input normalisation of the official code (default ImageNet RGB, and
            evsmap's indoor depth statistics for a depth network).
        note: where a setting comes from.
    """

    input_size: tuple[int, int]
    num_classes: int | None = None
    published: tuple[tuple[str, str], ...] = ()
    weights: tuple[WeightFile, ...] = ()
    normalization: Normalization | None = None
    note: str = ""


def _card(name: str, description: str, citation: str, dataset: str, setting: DatasetSetting,
          depth: str | None, note: str) -> ModelCard:
    class_set, classes = _CLASSES[dataset]
    norm = setting.normalization or (RGB_ONLY if depth is None else INDOOR)
    height, width = setting.input_size
    return ModelCard(
        name=f"{name}.{dataset}", segmenter=name, description=f"{description}; {dataset} "
        f"{setting.num_classes or classes} classes", citation=citation, dataset=dataset,
        input_size=(height, width), num_classes=setting.num_classes or classes,
        class_set=class_set, uses_depth=depth is not None, normalization=norm,
        options=(("dataset", dataset),),
        published=tuple(PaperFigure(quantity=q, cell=c) for q, c in setting.published),
        weights=tuple(setting.weights), note=" ".join(t for t in (note, setting.note) if t))


def register_network(name: str, *, build: str, description: str, citation: str,
                     datasets: Mapping[str, DatasetSetting], depth: str | None = None,
                     note: str = "") -> None:
    """Register segmenter ``name`` and its cards ``name.<dataset>`` (see the module notes).

    The factory takes ``dataset`` (default: the first of ``datasets``), ``num_classes``
    (default: the card's), ``backend``, ``weights`` and ``input_size``, like every network
    segmenter of evsmap.
    """
    if depth not in DEPTH_INPUTS:
        raise ValueError(f"{name}: depth must be one of {DEPTH_INPUTS}, got {depth!r}")
    unknown = sorted(set(datasets) - set(_CLASSES))
    if unknown or not datasets:
        raise ValueError(f"{name}: datasets must be some of {sorted(_CLASSES)}, got "
                         f"{sorted(datasets)}")
    module_name, _, function = build.partition(":")
    for dataset, setting in datasets.items():
        MODEL_CARDS.add(_card(name, description, citation, dataset, setting, depth, note))
    default = next(iter(datasets))

    def factory(*, dataset: str = default, num_classes: int | None = None,
                backend: str = "torch", weights: str | PathLike[str] | None = None,
                input_size: tuple[int, int] | None = None) -> NetworkSegmenter:
        key = str(dataset).lower()
        if key not in datasets:
            raise UnknownNameError(f"{name}: no card for dataset {dataset!r} (known: "
                                   f"{', '.join(datasets)})")
        card = MODEL_CARDS.get(f"{name}.{key}")
        classes = card.num_classes if num_classes is None else int(num_classes)
        builder = getattr(importlib.import_module(module_name), function)
        options = {"dataset": key} if "dataset" in inspect.signature(builder).parameters else {}
        return make_segmenter(
            name=name, module=builder(num_classes=classes, **options), card=card,
            num_classes=classes, depth=depth, backend=backend, weights=weights,
            input_size=input_size, config={"num_classes": classes, "dataset": key})

    factory.__name__ = name.replace("-", "_").replace(".", "_")
    first = datasets[default]
    # gate=False: the regression gates leave the compared networks out (timed in every
    # `evsmap reproduce` beside FEAGNet instead; see docs/gates.md, "What is gated")
    SEGMENTERS.add(name, factory, description=description, takes=NETWORK,
                   paper_size=tuple(first.input_size), gate=False)


def class_names(num_classes: int, dataset: str) -> tuple[str, ...]:
    """One name per class: the dataset's label set, with ``void`` first where the head keeps
    a void class (one class more than the set)."""
    _, classes = _CLASSES[dataset]
    outdoor = dataset == "cityscapes"
    if num_classes == classes + 1:
        return ("void", *class_names_for(classes, outdoor=outdoor))
    return tuple(class_names_for(num_classes, outdoor=outdoor))


def make_segmenter(*, name: str, module: Any, card: ModelCard, num_classes: int,
                   depth: str | None, backend: str, weights: Any, input_size: Any,
                   config: dict[str, Any]) -> NetworkSegmenter:
    """The segmenter of a built network: evsmap's :class:`NetworkSegmenter`, or for an HHA
    network :class:`baselines.hha.HHASegmenter` (its depth input is the three HHA
    channels)."""
    kwargs = dict(name=name, module=module, num_classes=num_classes,
                  class_names=class_names(num_classes, card.dataset),
                  uses_depth=depth is not None, default_size=card.input_size,
                  normalization=card.normalization, backend=backend, weights=weights,
                  input_size=input_size, config=config)
    if depth == "hha":
        from baselines.hha import HHASegmenter

        return HHASegmenter(**kwargs)
    from evsmap.segmenters.network import NetworkSegmenter

    return NetworkSegmenter(**kwargs)


assert set(CLASS_SETS) >= {s for s, _ in _CLASSES.values()}
