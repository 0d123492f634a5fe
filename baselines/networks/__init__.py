"""The networks of the paper's Tables I and II that evsmap compares FEAGNet with, each written
from its official code (docs/baselines.md) and registered as a segmenter with its model cards.

Every module of this package registers its networks when imported; importing the package
imports them all (the ``baselines`` plug-in does, through the ``evsmap.plugins`` entry point), so
a new network is one module here. Registration needs no torch: the networks are built when a
segmenter is made.
"""

from __future__ import annotations

import importlib
import pkgutil

for _info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
    if not _info.name.startswith("_"):
        importlib.import_module(f"{__name__}.{_info.name}")
