"""Registers the baseline networks as segmenters with their model cards
(:mod:`evsmap.segmenters.model_card`): ``esanet-r34-nbt1d`` (RGB-D) and ``fchardnet-70`` (RGB),
one card per training set (``esanet-r34-nbt1d.nyuv2``, ``.sunrgbd``, ``.cityscapes``; the same
for ``fchardnet-70``). A factory's ``dataset`` option picks the card, which gives the classes,
the input size and the normalisation."""

from __future__ import annotations

from os import PathLike
from typing import TYPE_CHECKING

from evsmap.classes import class_names_for
from evsmap.errors import UnknownNameError
from evsmap.registry import NETWORK, SEGMENTERS
from evsmap.segmenters.model_card import MODEL_CARDS, ModelCard, PaperFigure, WeightFile
from evsmap.segmenters.normalization import (
    CITYSCAPES_ESANET,
    INDOOR,
    SUNRGBD_ESANET,
    Normalization,
)
from evsmap.segmenters.official import ESANET, FCHARDNET

if TYPE_CHECKING:  # the networks import torch: only when one is made
    from evsmap.segmenters.network import NetworkSegmenter

RGB_ONLY = Normalization(depth_mean=0.0, depth_std=1.0)
"""ImageNet RGB statistics (FC-HarDNet reads no depth)."""

ESANET_PAPER = ("Seichter et al., 'Efficient RGB-D Semantic Segmentation for Indoor Scene "
                "Analysis', ICRA 2021 (ESANet)")
FCHARDNET_PAPER = "Chao et al., 'HarDNet: A Low Memory Traffic Network', ICCV 2019"

# dataset -> (input size, classes, class set); the label sets and sizes the baselines are
# trained at (NYUv2 and SUN RGB-D at 640x480, Cityscapes at 1024x512)
_DATASETS = {"nyuv2": ((480, 640), 40, "nyuv2-40"), "sunrgbd": ((480, 640), 37, "sunrgbd-37"),
             "cityscapes": ((512, 1024), 19, "cityscapes-19")}
_ESANET_NORMALIZATION = {"nyuv2": INDOOR, "sunrgbd": SUNRGBD_ESANET,
                         "cityscapes": CITYSCAPES_ESANET}
_ESANET_RELEASE = "github.com/TUI-NICR/ESANet (the README's pretrained weights)"
_ESANET_TENSORS = {"nyuv2": 898, "sunrgbd": 898, "cityscapes": 910}
_ESANET_FIGURES = {
    "nyuv2": ("table1", (("miou", "miou_nyuv2"), ("params", "params"), ("flops", "flops"),
                         ("fps", "fps"))),
    "sunrgbd": ("table1", (("miou", "miou_sunrgbd"),)),
    "cityscapes": ("table2", (("miou", "miou_1024"), ("fps", "fps_1024"), ("params", "params"))),
}


def _esanet_card(dataset: str) -> ModelCard:
    size, classes, class_set = _DATASETS[dataset]
    table, figures = _ESANET_FIGURES[dataset]
    return ModelCard(
        name=f"esanet-r34-nbt1d.{dataset}", segmenter="esanet-r34-nbt1d",
        description=f"ESANet-R34-NBt1D (Seichter et al. 2021): RGB-D baseline of Tables I, II, "
                    f"IV; {dataset} {classes} classes",
        citation=ESANET_PAPER, dataset=dataset, input_size=size, num_classes=classes,
        class_set=class_set, uses_depth=True, normalization=_ESANET_NORMALIZATION[dataset],
        options=(("dataset", dataset),),
        published=tuple(PaperFigure(quantity=q, cell=f"{table}/esanet-r34/{c}")
                        for q, c in figures),
        weights=(WeightFile(
            name=f"ESANet-R34-NBt1D {dataset} release", dataset=dataset, layout=ESANET,
            source=_ESANET_RELEASE,
            note=f"{{'state_dict': ...}} with {_ESANET_TENSORS[dataset]} tensors; loads as it "
                 f"is or through 'evsmap weights convert'"),),
        note="Depth statistics in the units of the dataset's depth files "
             "(src/datasets/<dataset>/pytorch_dataset.py of the official code).")


def _fchardnet_card(dataset: str) -> ModelCard:
    size, classes, class_set = _DATASETS[dataset]
    weights: tuple[WeightFile, ...] = ()
    if dataset == "cityscapes":
        weights = (WeightFile(
            name="hardnet70_cityscapes_model.pkl", dataset=dataset, layout=FCHARDNET,
            source="github.com/PingoLH/FCHarDNet",
            note="{'epoch', 'model_state', 'best_iou'}, 416 tensors behind DataParallel's "
                 "'module.' prefix; trained on BGR input, so the conversion reverses the first "
                 "convolution's input channels"),)
    return ModelCard(
        name=f"fchardnet-70.{dataset}", segmenter="fchardnet-70",
        description=f"FC-HarDNet-70 (Chao et al. 2019): RGB baseline of FEAGNet (Table III); "
                    f"{dataset} {classes} classes",
        citation=FCHARDNET_PAPER, dataset=dataset, input_size=size, num_classes=classes,
        class_set=class_set, uses_depth=False, normalization=RGB_ONLY,
        options=(("dataset", dataset),), weights=weights,
        note="The EVSMaP paper prints no figures of FC-HarDNet-70 itself.")


CARDS: tuple[ModelCard, ...] = (*(_esanet_card(d) for d in _DATASETS),
                                *(_fchardnet_card(d) for d in _DATASETS))
"""The baselines' model cards (registered in :data:`MODEL_CARDS`)."""

for _each in CARDS:
    MODEL_CARDS.add(_each)

_ESANET_DEPTH = {c.dataset: c.normalization for c in CARDS if c.segmenter == "esanet-r34-nbt1d"}
"""ESANet's normalisation per training set, from its cards (depth in the units of the files it
reads)."""


def _card(name: str, dataset: str) -> ModelCard:
    key = dataset.lower()
    if key not in _DATASETS:
        raise UnknownNameError(
            f"{name}: unknown dataset {dataset!r} (known: {', '.join(sorted(_DATASETS))})")
    return MODEL_CARDS.get(f"{name}.{key}")


def _network(name: str, dataset: str, num_classes: int | None, build, *, backend: str, weights,
             input_size) -> NetworkSegmenter:
    from evsmap.segmenters.network import NetworkSegmenter

    card = _card(name, dataset)
    classes = card.num_classes if num_classes is None else num_classes
    return NetworkSegmenter(
        name=name, module=build(classes, card.dataset), num_classes=classes,
        class_names=class_names_for(classes, outdoor=card.dataset == "cityscapes"),
        uses_depth=card.uses_depth, default_size=card.input_size,
        normalization=card.normalization, backend=backend, weights=weights,
        input_size=input_size, config={"num_classes": classes, "dataset": card.dataset})


@SEGMENTERS.register(
    "esanet-r34-nbt1d",
    takes=NETWORK,
    description="ESANet-R34-NBt1D (Seichter et al. 2021): RGB-D baseline of Tables I, II, IV",
    paper_size=(480, 640),
)
def esanet(
    *,
    num_classes: int | None = None,
    dataset: str = "nyuv2",
    backend: str = "torch",
    weights: str | PathLike[str] | None = None,
    input_size: tuple[int, int] | None = None,
) -> NetworkSegmenter:
    from baselines.esanet import esanet_r34_nbt1d

    return _network("esanet-r34-nbt1d", dataset, num_classes,
                    lambda c, d: esanet_r34_nbt1d(num_classes=c, dataset=d), backend=backend,
                    weights=weights, input_size=input_size)


@SEGMENTERS.register(
    "fchardnet-70",
    takes=NETWORK,
    description="FC-HarDNet-70 (Chao et al. 2019): RGB baseline of FEAGNet (Table III)",
    paper_size=(480, 640),
)
def fchardnet(
    *,
    num_classes: int | None = None,
    dataset: str = "nyuv2",
    backend: str = "torch",
    weights: str | PathLike[str] | None = None,
    input_size: tuple[int, int] | None = None,
) -> NetworkSegmenter:
    from baselines.fchardnet import fchardnet70

    return _network("fchardnet-70", dataset, num_classes, lambda c, d: fchardnet70(num_classes=c),
                    backend=backend, weights=weights, input_size=input_size)
