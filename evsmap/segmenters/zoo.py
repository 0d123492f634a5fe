"""Registers the FEAGNet variants as segmenters: ``feagnet-v1``, ``feagnet-v2`` (RGB-D, NYUv2
40 classes, 480x640) and ``feagnet-s``, ``feagnet-l`` (RGB only, Cityscapes 19 classes,
1024x512). The Table III ablation rows are the switches ``cfim``, ``dappf``, ``attention`` and
``multiscale`` (see :data:`evsmap.models.feagnet.ABLATIONS`)."""

from __future__ import annotations

from collections.abc import Callable
from os import PathLike

from evsmap.classes import class_names_for
from evsmap.models import feagnet as fg
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.network import INDOOR, NetworkSegmenter, Normalization

CITYSCAPES = Normalization(depth_mean=0.0, depth_std=1.0)
"""ImageNet RGB statistics (the S/L variants read no depth)."""

_VARIANTS: dict[str, tuple[Callable[..., fg.FEAGNet], int, tuple[int, int], bool, str]] = {
    "feagnet-v1": (fg.feagnet_v1, 40, (480, 640), True,
                   "FEAGNet-V1 (EVSMaP): RGB-D, strided init layer; NYUv2 40 classes"),
    "feagnet-v2": (fg.feagnet_v2, 40, (480, 640), True,
                   "FEAGNet-V2 (EVSMaP): RGB-D; NYUv2 40 classes"),
    "feagnet-s": (fg.feagnet_s, 19, (512, 1024), False,
                  "FEAGNet-S (EVSMaP): RGB only, strided init layer; Cityscapes 19 classes"),
    "feagnet-l": (fg.feagnet_l, 19, (512, 1024), False,
                  "FEAGNet-L (EVSMaP): RGB only; Cityscapes 19 classes"),
}


def _register(name: str) -> None:
    build, classes, size, depth, description = _VARIANTS[name]

    def factory(
        *,
        num_classes: int = classes,
        backend: str = "torch",
        weights: str | PathLike[str] | None = None,
        input_size: tuple[int, int] | None = None,
        cfim: bool = True,
        dappf: bool = True,
        attention: bool = True,
        multiscale: bool = True,
    ) -> NetworkSegmenter:
        switches = dict(dappf=dappf, attention=attention, multiscale=multiscale)
        if depth:
            switches["cfim"] = cfim
        module = build(num_classes=num_classes, **switches)
        return NetworkSegmenter(
            name=name, module=module, num_classes=num_classes,
            class_names=class_names_for(num_classes, outdoor=not depth), uses_depth=depth,
            default_size=size, normalization=INDOOR if depth else CITYSCAPES, backend=backend,
            weights=weights, input_size=input_size,
            config={"num_classes": num_classes, **switches})

    factory.__name__ = name.replace("-", "_")
    SEGMENTERS.add(name, factory, description=description, paper_size=size)


for _name in _VARIANTS:
    _register(_name)
