"""Registers the FEAGNet variants as segmenters, each with its model cards
(:mod:`evsmap.segmenters.model_card`): ``feagnet-v1``, ``feagnet-v2`` (RGB-D, NYUv2 40 classes,
480x640; cards ``.sunrgbd`` with 37 and ``.cityscapes`` with 19 classes) and ``feagnet-s``,
``feagnet-l`` (RGB only, Cityscapes 19 classes, 1024x512). The factories take their defaults
(classes, input size, depth, normalisation, description) from the default card. The Table III
ablation rows are the switches ``cfim``, ``dappf``, ``attention`` and ``multiscale`` (see
:data:`evsmap.models.feagnet.ABLATIONS`); ``cfim``, ``dappf`` and ``attention`` also take a
reading's name (``-o cfim=concat``, ``-o dappf=fullres``, ``-o attention=lbu``: the readings
before the Table III row fit)."""

from __future__ import annotations

import functools
from os import PathLike
from typing import TYPE_CHECKING

from evsmap.classes import class_names_for
from evsmap.registry import NETWORK, SEGMENTERS
from evsmap.segmenters.model_card import MODEL_CARDS, PAPER, ModelCard, PaperFigure
from evsmap.segmenters.normalization import INDOOR, Normalization

if TYPE_CHECKING:
    from evsmap.segmenters.network import NetworkSegmenter

CITYSCAPES = Normalization(depth_mean=0.0, depth_std=1.0)
"""ImageNet RGB statistics (the S/L variants read no depth)."""

_BUILDERS = {"feagnet-v1": "feagnet_v1", "feagnet-v2": "feagnet_v2", "feagnet-s": "feagnet_s",
             "feagnet-l": "feagnet_l"}
"""Segmenter -> its builder in :mod:`evsmap.models.feagnet`, looked up when a network is made
(naming the networks does not import torch)."""

_NO_WEIGHTS = ("The authors publish neither code nor weights; evsmap trains its own "
               "(docs/training.md).")
_TABLE_I = "Table I prints no input resolution; its FLOPs/FPS columns assume 640x480."
_TABLE_II = ("Table II measures it at 1024x512 and 2048x1024 (its columns' input sizes); the "
             "network is built at its default size unless input_size is given.")


def _figures(row: str, *columns: tuple[str, str], table: str = "table1",
             note: str = "") -> tuple[PaperFigure, ...]:
    return tuple(PaperFigure(quantity=q, cell=f"{table}/{row}/{c}", note=note) for q, c in columns)


def _rgbd(name: str, label: str, init: str, row: str) -> tuple[ModelCard, ...]:
    card = functools.partial(ModelCard, segmenter=name, citation=PAPER, input_size=(480, 640),
                             uses_depth=True, normalization=INDOOR)
    text = ("Section IV-C1: 'both versions of our FEAGNet reached 4.5M, with computational "
            "costs of 1.9 GFLOPs and 7.8 GFLOPs'")
    return (
        card(name=name, description=f"{label} (EVSMaP): RGB-D{init}; NYUv2 40 classes",
             dataset="nyuv2", num_classes=40, class_set="nyuv2-40",
             published=_figures(row, ("miou", "miou_nyuv2"), ("params", "params"),
                                ("flops", "flops"), ("fps", "fps"), note=text),
             note=f"{_TABLE_I} {_NO_WEIGHTS}"),
        card(name=f"{name}.sunrgbd",
             description=f"{label} (EVSMaP): RGB-D{init}; SUN RGB-D 37 classes",
             dataset="sunrgbd", num_classes=37, class_set="sunrgbd-37",
             options=(("num_classes", 37),),
             published=_figures(row, ("miou", "miou_sunrgbd")),
             note=f"{_TABLE_I} {_NO_WEIGHTS}"),
        card(name=f"{name}.cityscapes",
             description=f"{label} (EVSMaP): RGB-D{init}; Cityscapes 19 classes",
             dataset="cityscapes", num_classes=19, class_set="cityscapes-19",
             options=(("num_classes", 19),),
             published=_figures(row, ("miou", "miou_1024"), ("params", "params"),
                                table="table2"),
             note=f"{_TABLE_II} {_NO_WEIGHTS}"),
    )


def _rgb(name: str, label: str, init: str) -> ModelCard:
    text = "Section IV-C2: 'With only RGB input, our Model size is 2.8M'"
    return ModelCard(
        name=name, segmenter=name, citation=PAPER,
        description=f"{label} (EVSMaP): RGB only{init}; Cityscapes 19 classes",
        dataset="cityscapes", input_size=(512, 1024), num_classes=19,
        class_set="cityscapes-19", uses_depth=False, normalization=CITYSCAPES,
        published=_figures(name, ("miou", "miou_1024"), ("fps", "fps_1024"),
                           ("params", "params"), table="table2", note=text),
        note=_NO_WEIGHTS)


CARDS: tuple[ModelCard, ...] = (
    *_rgbd("feagnet-v1", "FEAGNet-V1", ", strided init layer", "feagnet-v1"),
    *_rgbd("feagnet-v2", "FEAGNet-V2", "", "feagnet-v2"),
    _rgb("feagnet-s", "FEAGNet-S", ", strided init layer"),
    _rgb("feagnet-l", "FEAGNet-L", ""),
)
"""The FEAGNet model cards (registered in :data:`MODEL_CARDS`)."""


def _register(card: ModelCard) -> None:
    name, builder = card.name, _BUILDERS[card.name]
    size, depth, normalization = card.input_size, card.uses_depth, card.normalization

    def factory(
        *,
        num_classes: int = card.num_classes,
        backend: str = "torch",
        weights: str | PathLike[str] | None = None,
        input_size: tuple[int, int] | None = None,
        cfim: bool | str = True,
        dappf: bool | str = True,
        attention: bool | str = True,
        multiscale: bool = True,
        postprocess: str = "network",
    ) -> NetworkSegmenter:
        from evsmap.errors import EvsmapError
        from evsmap.models import feagnet
        from evsmap.segmenters.network import NetworkSegmenter

        switches = dict(dappf=dappf, attention=attention, multiscale=multiscale)
        if depth:
            switches["cfim"] = cfim
        try:
            module = getattr(feagnet, builder)(num_classes=num_classes, **switches)
        except ValueError as exc:  # an unknown reading name: a user error
            raise EvsmapError(f"segmenter {name!r}: {exc}") from None
        return NetworkSegmenter(
            name=name, module=module, num_classes=num_classes,
            class_names=class_names_for(num_classes, outdoor=not depth), uses_depth=depth,
            default_size=size, normalization=normalization, backend=backend,
            weights=weights, input_size=input_size, postprocess=postprocess,
            config={"num_classes": num_classes, **switches})

    factory.__name__ = name.replace("-", "_")
    SEGMENTERS.add(name, factory, description=card.description, takes=NETWORK, paper_size=size)


for _card in CARDS:
    MODEL_CARDS.add(_card)
    if _card.name == _card.segmenter:
        _register(_card)
