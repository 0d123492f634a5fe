"""Files of a training run: atomic writes, the resumable checkpoint, the weights files with their
card, random-number-generator states.

``OUT/checkpoint.pt`` (the resume point, rewritten after every epoch)::

    {"format": "evsmap-train-checkpoint", "version": 1,
     "state_dict": {...},          # the model (DDP's "module." removed)
     "card": {...},                # as in last.pt: the file also loads through --weights
     "optimizer": {...}, "scheduler": {...}, "scaler": {...} | None,
     "rng": {"torch", "cuda", "numpy", "python"},   # of rank 0 after the epoch
     "epoch": N,                   # epochs completed
     "recipe": {...}, "run": {...}, "history": [row, ...], "best": {...} | None}

``OUT/last.pt`` and ``OUT/best.pt``: ``{"state_dict": ..., "card": ...}`` - weights files for
``--weights`` / ``weights=``. Everything is plain data and tensors, read back with
``torch.load(weights_only=True)`` (:func:`evsmap.segmenters.weights.read_checkpoint`). Every
file is written to a temporary name in the same folder, flushed to disk and renamed over the
old one (``os.replace``), so a crash leaves the previous complete file.
"""

from __future__ import annotations

import os
import random
from typing import Any

import numpy as np
import torch

from evsmap.errors import DataFormatError
from evsmap.fileio import atomic_write

FORMAT = "evsmap-train-checkpoint"
VERSION = 1
CHECKPOINT = "checkpoint.pt"
LAST = "last.pt"
BEST = "best.pt"
LOG = "log.csv"
RUN = "run.json"


def atomic_save(obj: Any, path: str | os.PathLike[str]) -> None:
    """``torch.save(obj)`` to ``path`` through :func:`evsmap.fileio.atomic_write`, flushed to disk
    with its folder: a crash leaves the previous complete file."""
    with atomic_write(path, "wb", durable=True) as fh:
        torch.save(obj, fh)


def save_weights(path: str | os.PathLike[str], state_dict: dict[str, torch.Tensor],
                 card: dict[str, Any]) -> None:
    """A weights file: ``{"state_dict": ..., "card": ...}`` (tensors moved to the CPU)."""
    atomic_save({"state_dict": cpu_state(state_dict), "card": card}, path)


def cpu_state(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    return {k: v.detach().cpu() for k, v in state.items()}


def load_checkpoint(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A training checkpoint written by :func:`atomic_save` in the loop (weights-only read).

    Raises:
        DataFormatError: missing, unreadable, or not an evsmap training checkpoint.
    """
    from evsmap.segmenters.weights import read_checkpoint

    obj = read_checkpoint(path)
    if not isinstance(obj, dict) or obj.get("format") != FORMAT:
        raise DataFormatError(f"{path}: not an evsmap training checkpoint (no \"format\": "
                              f"\"{FORMAT}\")")
    if obj.get("version") != VERSION:
        raise DataFormatError(f"{path}: training checkpoint version {obj.get('version')}, this "
                              f"evsmap reads version {VERSION}")
    return obj


# -- random number generators ----------------------------------------------------------------------

def rng_state() -> dict[str, Any]:
    """The states of torch's (CPU and CUDA), numpy's global and Python's generators, as plain
    data and tensors."""
    np_state = np.random.get_state(legacy=False)  # noqa: NPY002  (the global generator)
    cuda = torch.cuda.get_rng_state_all() if torch.cuda.is_available() and \
        torch.cuda.is_initialized() else []
    return {
        "torch": torch.get_rng_state(),
        "cuda": list(cuda),
        "numpy": {"bit_generator": np_state["bit_generator"],
                  "key": [int(v) for v in np_state["state"]["key"]],
                  "pos": int(np_state["state"]["pos"]),
                  "has_gauss": int(np_state["has_gauss"]), "gauss": float(np_state["gauss"])},
        "python": random.getstate(),
    }


def set_rng_state(state: dict[str, Any]) -> None:
    """Restore what :func:`rng_state` returned."""
    torch.set_rng_state(state["torch"])
    if state.get("cuda") and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])
    n = state["numpy"]
    np_state = {"bit_generator": n["bit_generator"],
                "state": {"key": np.asarray(n["key"], dtype=np.uint32), "pos": n["pos"]},
                "has_gauss": n["has_gauss"], "gauss": n["gauss"]}
    np.random.set_state(np_state)  # noqa: NPY002  (the global generator)
    py = state["python"]
    random.setstate((py[0], tuple(py[1]), py[2]))


def derived_seed(*parts: int) -> int:
    """A 63-bit seed from integers (the run's seed, an epoch, a rank), by numpy's SeedSequence."""
    words = np.random.SeedSequence([int(p) for p in parts]).generate_state(2, dtype=np.uint32)
    return (int(words[0]) << 31) ^ int(words[1])


def seed_everything(seed: int) -> None:
    """Seed torch (CPU and every CUDA device), numpy's global and Python's generators."""
    random.seed(seed)
    np.random.seed(seed % 2**32)  # noqa: NPY002  (the global generator others may use)
    torch.manual_seed(seed)


__all__ = ["BEST", "CHECKPOINT", "FORMAT", "LAST", "LOG", "RUN", "VERSION", "atomic_save",
           "cpu_state", "derived_seed", "load_checkpoint", "rng_state",
           "save_weights", "seed_everything", "set_rng_state"]
