"""Weight cards: the record every weights file evsmap writes carries beside its ``state_dict``.

A weights file is ``{"state_dict": {key: tensor}, "card": {...}}`` (``torch.save``); it loads
wherever ``--weights`` / ``weights=`` is taken (the loader unwraps ``state_dict``) and is
recognised as the ``evsmap`` layout (:mod:`evsmap.segmenters.official`). The card is a flat dict
of plain values (str, int, float, bool, None, lists, dicts of those), readable with
``torch.load(weights_only=True)`` and JSON-serialisable. Every card has:

``card_version``    :data:`CARD_VERSION`
``model``           registered segmenter name
``options``         segmenter options that build the network the tensors fit
``num_classes``     classes of the classifier
``class_names``     one name per class
``evsmap_version``  version of evsmap that wrote the file
``git_commit``      commit of the evsmap source tree that wrote it (``+dirty`` when it had
                    uncommitted changes; None outside a git checkout)
``tensors``         number of tensors
``tensors_sha256``  :func:`tensor_sha256` of the state dict

plus what the writer knows: ``evsmap weights convert`` adds the source file and layout,
``evsmap train`` the dataset, splits, recipe, epochs and measured mIoU (see
``docs/training.md``). Readers must ignore keys they do not know.
"""

from __future__ import annotations

import subprocess
from collections.abc import Mapping
from functools import cache
from pathlib import Path
from typing import Any

from evsmap.segmenters.weights import tensors_sha256
from evsmap.version import evsmap_version

CARD_VERSION = 1

tensor_sha256 = tensors_sha256
"""SHA-256 over a state dict's tensors: for each key in sorted order the key, dtype, shape and
raw bytes (:func:`evsmap.segmenters.weights.tensors_sha256`)."""


@cache
def git_commit() -> str | None:
    """The commit of the git checkout evsmap runs from (``<sha>+dirty`` with uncommitted changes
    to tracked files), None when it is not a checkout or git is unavailable."""
    root = Path(__file__).resolve().parents[2]
    try:
        sha = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True,
                             text=True, timeout=10, check=True).stdout.strip()
        status = subprocess.run(["git", "-C", str(root), "status", "--porcelain",
                                 "--untracked-files=no"], capture_output=True, text=True,
                                timeout=30, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    if not sha:
        return None
    return sha + ("+dirty" if status else "")


def make_card(*, model: str, options: Mapping[str, Any], num_classes: int,
              class_names: list[str] | tuple[str, ...], state_dict: Mapping[str, Any],
              **fields: Any) -> dict[str, Any]:
    """A card for ``state_dict``: the common keys above, then ``fields`` (the writer's own)."""
    card: dict[str, Any] = {
        "card_version": CARD_VERSION,
        "model": model,
        "options": dict(options),
        "num_classes": int(num_classes),
        "class_names": [str(n) for n in class_names],
        "evsmap_version": evsmap_version(),
        "git_commit": git_commit(),
        "tensors": len(state_dict),
        "tensors_sha256": tensor_sha256(state_dict),
    }
    card.update(fields)
    return card


__all__ = ["CARD_VERSION", "evsmap_version", "git_commit", "make_card", "tensor_sha256"]
