"""Registers the baseline networks as segmenters: ``esanet-r34-nbt1d`` (RGB-D) and
``fchardnet-70`` (RGB)."""

from __future__ import annotations

from os import PathLike
from typing import TYPE_CHECKING

from evsmap.classes import class_names_for
from evsmap.errors import UnknownNameError
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.normalization import (
    CITYSCAPES_ESANET,
    INDOOR,
    SUNRGBD_ESANET,
    Normalization,
)

if TYPE_CHECKING:  # the networks import torch: only when one is made
    from evsmap.segmenters.network import NetworkSegmenter

_SIZES = {"nyuv2": (480, 640), "sunrgbd": (480, 640), "cityscapes": (512, 1024)}
_CLASSES = {"nyuv2": 40, "sunrgbd": 37, "cityscapes": 19}
RGB_ONLY = Normalization(depth_mean=0.0, depth_std=1.0)
"""ImageNet RGB statistics (FC-HarDNet reads no depth)."""
_ESANET_DEPTH = {"nyuv2": INDOOR, "sunrgbd": SUNRGBD_ESANET, "cityscapes": CITYSCAPES_ESANET}
"""ESANet's depth statistics per training set, each in the units of the depth files it reads
(``src/datasets/<dataset>/pytorch_dataset.py`` of the official code)."""


def _dataset(name: str, dataset: str) -> str:
    key = dataset.lower()
    if key not in _SIZES:
        raise UnknownNameError(
            f"{name}: unknown dataset {dataset!r} (known: {', '.join(sorted(_SIZES))})")
    return key


def _network(name: str, dataset: str, num_classes: int | None, build, *, uses_depth: bool,
             backend: str, weights, input_size) -> NetworkSegmenter:
    from evsmap.segmenters.network import NetworkSegmenter

    key = _dataset(name, dataset)
    classes = _CLASSES[key] if num_classes is None else num_classes
    return NetworkSegmenter(
        name=name, module=build(classes, key), num_classes=classes,
        class_names=class_names_for(classes, outdoor=key == "cityscapes"),
        uses_depth=uses_depth, default_size=_SIZES[key],
        normalization=_ESANET_DEPTH[key] if uses_depth else RGB_ONLY, backend=backend,
        weights=weights,
        input_size=input_size, config={"num_classes": classes, "dataset": key})


@SEGMENTERS.register(
    "esanet-r34-nbt1d",
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
                    lambda c, d: esanet_r34_nbt1d(num_classes=c, dataset=d), uses_depth=True,
                    backend=backend, weights=weights, input_size=input_size)


@SEGMENTERS.register(
    "fchardnet-70",
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

    return _network("fchardnet-70", dataset, num_classes,
                    lambda c, d: fchardnet70(num_classes=c), uses_depth=False,
                    backend=backend, weights=weights, input_size=input_size)
