"""Registers the FEAGNet variants as segmenters: ``feagnet-v1``, ``feagnet-v2`` (RGB-D, NYUv2
40 classes, 480x640) and ``feagnet-s``, ``feagnet-l`` (RGB only, Cityscapes 19 classes,
1024x512). The Table III ablation rows are the switches ``cfim``, ``dappf``, ``attention`` and
``multiscale`` (see :data:`evsmap.models.feagnet.ABLATIONS`); ``cfim``, ``dappf`` and
``attention`` also take a reading's name (``-o cfim=concat``, ``-o dappf=fullres``,
``-o attention=lbu``: the readings before the Table III row fit)."""

from __future__ import annotations

from os import PathLike
from typing import TYPE_CHECKING

from evsmap.classes import class_names_for
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.normalization import INDOOR, Normalization

if TYPE_CHECKING:
    from evsmap.segmenters.network import NetworkSegmenter

CITYSCAPES = Normalization(depth_mean=0.0, depth_std=1.0)
"""ImageNet RGB statistics (the S/L variants read no depth)."""

# name -> (builder in evsmap.models.feagnet, classes, paper size, reads depth, description); the
# builders are looked up when a network is made, so naming the networks does not import torch
_VARIANTS: dict[str, tuple[str, int, tuple[int, int], bool, str]] = {
    "feagnet-v1": ("feagnet_v1", 40, (480, 640), True,
                   "FEAGNet-V1 (EVSMaP): RGB-D, strided init layer; NYUv2 40 classes"),
    "feagnet-v2": ("feagnet_v2", 40, (480, 640), True,
                   "FEAGNet-V2 (EVSMaP): RGB-D; NYUv2 40 classes"),
    "feagnet-s": ("feagnet_s", 19, (512, 1024), False,
                  "FEAGNet-S (EVSMaP): RGB only, strided init layer; Cityscapes 19 classes"),
    "feagnet-l": ("feagnet_l", 19, (512, 1024), False,
                  "FEAGNet-L (EVSMaP): RGB only; Cityscapes 19 classes"),
}


def _register(name: str) -> None:
    builder, classes, size, depth, description = _VARIANTS[name]

    def factory(
        *,
        num_classes: int = classes,
        backend: str = "torch",
        weights: str | PathLike[str] | None = None,
        input_size: tuple[int, int] | None = None,
        cfim: bool | str = True,
        dappf: bool | str = True,
        attention: bool | str = True,
        multiscale: bool = True,
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
            default_size=size, normalization=INDOOR if depth else CITYSCAPES, backend=backend,
            weights=weights, input_size=input_size,
            config={"num_classes": num_classes, **switches})

    factory.__name__ = name.replace("-", "_")
    SEGMENTERS.add(name, factory, description=description, paper_size=size)


for _name in _VARIANTS:
    _register(_name)
