"""Segmentation datasets: readers of NYUv2, SUN RGB-D and Cityscapes and the ``prepare_*``
functions behind ``evsmap datasets prepare`` (see ``datasets/README.md``).

The readers register themselves in :data:`evsmap.registry.READERS` (``nyuv2``, ``sunrgbd``,
``cityscapes``) when their modules are imported; :func:`get_preparer` imports a module on demand.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

from evsmap.errors import UnknownNameError

DATASETS: dict[str, str] = {
    "nyuv2": "NYU Depth v2 labelled set, 40 classes (795 train / 654 test)",
    "sunrgbd": "SUN RGB-D, 37 classes (5285 train / 5050 test)",
    "cityscapes": "Cityscapes, 19 classes (2975 train / 500 val / 1525 test)",
}
"""Datasets that ``evsmap datasets prepare`` knows, with a one-line description."""


def get_preparer(name: str) -> Callable[..., dict]:
    """``prepare_<name>(source_dir, out_dir, *, limit, overwrite, progress, ...)``."""
    if name not in DATASETS:
        raise UnknownNameError(f"unknown dataset {name!r} (known: {', '.join(DATASETS)})")
    module = importlib.import_module(f"evsmap.datasets.{name}")
    return getattr(module, f"prepare_{name}")
