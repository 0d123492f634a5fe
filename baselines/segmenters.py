"""Registers the baseline networks as segmenters: ``esanet-r34-nbt1d`` (RGB-D) and
``fchardnet-70`` (RGB)."""

from __future__ import annotations

from os import PathLike

from baselines.esanet import DATASET_CONFIGS, esanet_r34_nbt1d
from baselines.fchardnet import fchardnet70
from evsmap.classes import class_names_for
from evsmap.errors import UnknownNameError
from evsmap.registry import SEGMENTERS
from evsmap.segmenters.network import INDOOR, NetworkSegmenter, Normalization

_SIZES = {"nyuv2": (480, 640), "sunrgbd": (480, 640), "cityscapes": (512, 1024)}
_CLASSES = {"nyuv2": 40, "sunrgbd": 37, "cityscapes": 19}


def _dataset(name: str, dataset: str) -> str:
    key = dataset.lower()
    if key not in _SIZES:
        raise UnknownNameError(
            f"{name}: unknown dataset {dataset!r} (known: {', '.join(sorted(_SIZES))})")
    return key


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
    key = _dataset("esanet-r34-nbt1d", dataset)
    assert key in DATASET_CONFIGS
    classes = _CLASSES[key] if num_classes is None else num_classes
    return NetworkSegmenter(
        name="esanet-r34-nbt1d", module=esanet_r34_nbt1d(num_classes=classes, dataset=key),
        num_classes=classes, class_names=class_names_for(classes, outdoor=key == "cityscapes"),
        uses_depth=True, default_size=_SIZES[key], normalization=INDOOR, backend=backend,
        weights=weights, input_size=input_size,
        config={"num_classes": classes, "dataset": key})


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
    key = _dataset("fchardnet-70", dataset)
    classes = _CLASSES[key] if num_classes is None else num_classes
    return NetworkSegmenter(
        name="fchardnet-70", module=fchardnet70(num_classes=classes), num_classes=classes,
        class_names=class_names_for(classes, outdoor=key == "cityscapes"), uses_depth=False,
        default_size=_SIZES[key], normalization=Normalization(depth_mean=0.0, depth_std=1.0),
        backend=backend, weights=weights, input_size=input_size,
        config={"num_classes": classes, "dataset": key})
