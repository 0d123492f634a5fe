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
                    uncommitted changes; None outside a git checkout), as every record names
                    it (:func:`evsmap.environment.collect_environment`)
``tensors``         number of tensors
``tensors_sha256``  :func:`tensor_sha256` of the state dict
``machine``         where it was written: ``cpu`` and ``instruction_set``
                    (:func:`evsmap.environment.collect_environment`'s keys; the kernels a
                    trained network's arithmetic ran on). Cards written before it lack the key.

plus what the writer knows: ``evsmap weights convert`` adds the source file and layout,
``evsmap train`` the dataset, splits, recipe, epochs and measured mIoU (see
``docs/training.md``). Readers must ignore keys they do not know.

Reading them back (``evsmap weights`` and the runner's weights folder):
:func:`find_weights_files` lists the files, :func:`inspect_weights` / :func:`open_weights` read
a file's card with its tensors memory-mapped, and :func:`card_spec`, :func:`card_dataset`,
:func:`card_miou` and :func:`format_options` read a card's fields. The module loads without
torch; it is imported when a file is read or a card made.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from evsmap.environment import collect_environment
from evsmap.errors import DataFormatError, EvsmapError
from evsmap.version import evsmap_version

CARD_VERSION = 1
WEIGHTS_SUFFIXES = (".pt", ".pth")
"""What ``weights list`` and the runner's weights folder look for."""
TRAIN_CHECKPOINT = "evsmap-train-checkpoint"
"""``format`` of ``evsmap train``'s resume point (``checkpoint.pt``), a weights file too."""


def tensor_sha256(state_dict: Mapping[str, Any]) -> str:
    """SHA-256 over a state dict's tensors: for each key in sorted order the key, dtype, shape
    and raw bytes (:func:`evsmap.segmenters.weights.tensors_sha256`, imported on first use:
    this module loads without torch)."""
    from evsmap.segmenters.weights import tensors_sha256

    return tensors_sha256(state_dict)


def make_card(*, model: str, options: Mapping[str, Any], num_classes: int,
              class_names: list[str] | tuple[str, ...], state_dict: Mapping[str, Any],
              **fields: Any) -> dict[str, Any]:
    """A card for ``state_dict``: the common keys above, then ``fields`` (the writer's own)."""
    env = collect_environment()
    card: dict[str, Any] = {
        "card_version": CARD_VERSION,
        "model": model,
        "options": dict(options),
        "num_classes": int(num_classes),
        "class_names": [str(n) for n in class_names],
        "evsmap_version": evsmap_version(),
        "git_commit": env["git_commit"],
        "tensors": len(state_dict),
        "tensors_sha256": tensor_sha256(state_dict),
        "machine": {key: env[key] for key in ("cpu", "instruction_set")},
    }
    card.update(fields)
    return card


# ----------------------------------------------------------------------------- reading files
@dataclass
class WeightsFile:
    """A weights file as ``weights list`` sees it (its tensors not read).

    Attributes:
        path: the file.
        size: its size in bytes.
        card: its card (None: it has none).
        layout: the state dict's layout (a key of :data:`evsmap.segmenters.official.LAYOUTS`);
            None when unreadable.
        tensors: number of tensors of the state dict.
        checkpoint: the file is ``evsmap train``'s resume point (it also loads as weights).
        error: why the file cannot be read as weights (one line), else None.
    """

    path: Path
    size: int
    card: dict[str, Any] | None = None
    layout: str | None = None
    tensors: int | None = None
    checkpoint: bool = False
    error: str | None = None

    def describe(self) -> str:
        """What the file is, for a file without a card or an unreadable one."""
        from evsmap.segmenters.official import ESANET, FCHARDNET, LAYOUTS

        if self.error is not None:
            return f"unreadable: {self.error}"
        if self.card is not None:
            return "evsmap training checkpoint with a card" if self.checkpoint else \
                "evsmap weights file with a card"
        if self.layout in (ESANET, FCHARDNET):
            return (f"no card (official release layout {self.layout}: {LAYOUTS[self.layout]}, "
                    f"{self.tensors} tensors)")
        return f"no card ({LAYOUTS.get(str(self.layout), self.layout)}, {self.tensors} tensors)"

    def as_dict(self) -> dict[str, Any]:
        card = self.card
        return {"file": str(self.path), "size_bytes": self.size, "layout": self.layout,
                "tensors": self.tensors, "checkpoint": self.checkpoint, "error": self.error,
                "model": card_get(card, "model"), "options": card_get(card, "options"),
                "spec": card_spec(card) if card else None, "dataset": card_dataset(card),
                "num_classes": card_get(card, "num_classes"),
                "val_miou": card_miou(card, "val"), "test_miou": card_miou(card, "test"),
                "card": card}


def load_lazily(path: str | os.PathLike[str]) -> object:
    """The object in a weights file with its tensors memory-mapped, not read:
    ``torch.load(weights_only=True, mmap=True)`` with the numpy allow-list of
    :func:`~evsmap.segmenters.weights.read_checkpoint` (a legacy non-zip file, which cannot be
    mapped, is read whole).

    Raises:
        DataFormatError: missing, empty or unreadable (one line).
    """
    from evsmap.segmenters.weights import read_checkpoint

    path = Path(path)
    if path.is_file() and path.stat().st_size == 0:
        raise DataFormatError(f"{path}: empty file")
    return read_checkpoint(path, mmap=True)


def open_weights(path: str | os.PathLike[str]) -> tuple[WeightsFile, dict[str, Any]]:
    """The file's description and its state dict (tensors memory-mapped).

    Raises:
        DataFormatError: unreadable, or not a state dict.
    """
    from evsmap.segmenters.official import detect_layout
    from evsmap.segmenters.weights import _unwrap

    path = Path(path)
    obj = load_lazily(path)
    state = _unwrap(obj, path)
    card = obj.get("card") if isinstance(obj, dict) else None
    card = dict(card) if isinstance(card, Mapping) else None
    info = WeightsFile(path=path, size=path.stat().st_size, card=card,
                       layout=detect_layout(state, card), tensors=len(state),
                       checkpoint=isinstance(obj, dict) and obj.get("format") == TRAIN_CHECKPOINT)
    return info, state


def inspect_weights(path: str | os.PathLike[str]) -> WeightsFile:
    """:func:`open_weights` without the tensors; an unreadable file gets its ``error``."""
    path = Path(path)
    try:
        return open_weights(path)[0]
    except DataFormatError as exc:
        size = path.stat().st_size if path.is_file() else 0
        reason = str(exc)
        prefix = f"{path}: "
        return WeightsFile(path=path, size=size,
                           error=reason[len(prefix):] if reason.startswith(prefix) else reason)


def find_weights_files(paths: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """Each path that is a file, and the ``*.pt`` / ``*.pth`` files under each folder
    (recursively, in sorted order; hidden files and folders skipped, links to folders not
    followed).

    Raises:
        EvsmapError: a path that does not exist.
    """
    out: list[Path] = []
    for given in paths:
        given = Path(given)
        if given.is_file():
            out.append(given)
            continue
        if not given.is_dir():
            raise EvsmapError(f"{given}: no such file or folder")
        for root, dirs, files in os.walk(given):
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
            for name in sorted(files):
                if not name.startswith(".") and name.lower().endswith(WEIGHTS_SUFFIXES):
                    out.append(Path(root) / name)
    return out


# ----------------------------------------------------------------------------- card fields
def card_get(card: Mapping[str, Any] | None, key: str) -> Any:
    return card.get(key) if isinstance(card, Mapping) else None


def card_dataset(card: Mapping[str, Any] | None) -> str | None:
    """The dataset a card's weights were trained on, as the runner names datasets: the reader
    ``evsmap train`` read it with (``nyuv2``, ``synthrooms``, ...), else the ``dataset`` field
    (a folder's name when it is a path), else the ``dataset`` option (``convert``'s cards of
    the official ESANet / FC-HarDNet releases: the configuration the release was trained
    on)."""
    reader, dataset = card_get(card, "reader"), card_get(card, "dataset")
    if isinstance(reader, str) and reader:
        return reader
    if isinstance(dataset, str) and dataset:
        return Path(dataset).name if ("/" in dataset or os.sep in dataset) else dataset
    options = card_get(card, "options")
    option = options.get("dataset") if isinstance(options, Mapping) else None
    return option if isinstance(option, str) and option else None


def card_miou(card: Mapping[str, Any] | None, split: str) -> float | None:
    """The card's measured mIoU on ``split`` (``val`` or ``test``) as a fraction, else None
    (``<split>_miou``; also read: ``miou_<split>`` and a ``metrics`` table of either)."""
    if not isinstance(card, Mapping):
        return None
    metrics = card.get("metrics")
    metrics = metrics if isinstance(metrics, Mapping) else {}
    for where, key in ((card, f"{split}_miou"), (card, f"miou_{split}"),
                       (metrics, f"{split}_miou"), (metrics, f"miou_{split}"),
                       (metrics, split)):
        value = where.get(key)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            try:
                number = float(value)
            except OverflowError:  # an integer beyond the float range
                continue
            if math.isfinite(number):
                return number
    return None


def _option_text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def format_options(options: Any) -> str:
    """``k=v,...`` in sorted order (bools as true/false), as in the runner's specs."""
    if not isinstance(options, Mapping):
        return ""
    return ",".join(f"{k}={_option_text(v)}"
                    for k, v in sorted(options.items(), key=lambda kv: str(kv[0])))


def card_spec(card: Mapping[str, Any] | None) -> str:
    """``model`` or ``model(k=v,...)`` from the card's options."""
    model = str(card_get(card, "model") or "?")
    opts = format_options(card_get(card, "options"))
    return f"{model}({opts})" if opts else model


__all__ = ["CARD_VERSION", "TRAIN_CHECKPOINT", "WEIGHTS_SUFFIXES", "WeightsFile", "card_dataset",
           "card_get", "card_miou", "card_spec", "evsmap_version", "find_weights_files",
           "format_options", "inspect_weights", "load_lazily", "make_card",
           "open_weights", "tensor_sha256"]
