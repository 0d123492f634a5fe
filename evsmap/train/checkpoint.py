"""Files of a training run: atomic writes, the resumable checkpoint, the weights files with their
card, the log, random-number-generator states.

``OUT/checkpoint.pt`` (the resume point, rewritten after every epoch)::

    {"format": "evsmap-train-checkpoint", "version": 1,
     "state_dict": {...},          # the model (DDP's "module." removed)
     "card": {...},                # as in last.pt: the file also loads through --weights
     "optimizer": {...}, "scheduler": {...}, "scaler": {...} | None,   # AMP's GradScaler
     "rng": {"torch", "cuda", "numpy", "python"},   # of rank 0 after the epoch
     "backends": {"cudnn_benchmark", ...},          # torch's algorithm flags (backend_flags)
     "epoch": N,                   # epochs completed
     "recipe": {...}, "run": {...}, "history": [row, ...], "best": {...} | None}

``OUT/last.pt`` and ``OUT/best.pt``: ``{"state_dict": ..., "card": ...}`` - weights files for
``--weights`` / ``weights=``. Everything is plain data and tensors, read back with
``torch.load(weights_only=True)`` (:func:`evsmap.segmenters.weights.read_checkpoint`). Every
file is written to a temporary name in the same folder, flushed to disk and renamed over the
old one (``os.replace``), so a crash leaves the previous complete file.
"""

from __future__ import annotations

import csv
import io
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
LOG_COLUMNS = ("epoch", "lr", "loss", "val_miou", "train_seconds", "val_seconds", "seconds",
               "images", "images_per_s")
"""The columns of ``log.csv``, one row per epoch."""


def atomic_save(obj: Any, path: str | os.PathLike[str]) -> None:
    """``torch.save(obj)`` to ``path`` through :func:`evsmap.fileio.atomic_write`, flushed to disk
    with its folder: a crash leaves the previous complete file."""
    with atomic_write(path, "wb", durable=True) as fh:
        torch.save(obj, fh)


def save_weights(path: str | os.PathLike[str], state_dict: dict[str, torch.Tensor],
                 card: dict[str, Any]) -> None:
    """A weights file: ``{"state_dict": ..., "card": ...}`` (tensors moved to the CPU)."""
    atomic_save({"state_dict": cpu_state(state_dict), "card": card}, path)


def read_weights_file(path: str | os.PathLike[str]) -> tuple[dict[str, torch.Tensor],
                                                             dict[str, Any]]:
    """The state dict and card of a weights file :func:`save_weights` wrote.

    Raises:
        DataFormatError: missing, unreadable, or without a state dict and a card.
    """
    from evsmap.segmenters.weights import read_checkpoint

    obj = read_checkpoint(path)
    if not isinstance(obj, dict) or not isinstance(obj.get("state_dict"), dict) \
            or not isinstance(obj.get("card"), dict):
        raise DataFormatError(f"{path}: not a weights file with a card")
    return obj["state_dict"], dict(obj["card"])


def log_csv(rows: list[dict[str, Any]]) -> str:
    """The text of ``log.csv``: a header of :data:`LOG_COLUMNS`, then one line per row (None
    as an empty field)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=LOG_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if row.get(k) is None else row[k]) for k in LOG_COLUMNS})
    return buf.getvalue()


def cpu_state(state: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    return {k: v.detach().cpu() for k, v in state.items()}


def load_checkpoint(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A training checkpoint written by :func:`atomic_save` in the loop (weights-only read).

    Raises:
        DataFormatError: missing, unreadable, or not an evsmap training checkpoint.
    """
    from evsmap.segmenters.weights import read_checkpoint

    obj = read_checkpoint(path)
    if not isinstance(obj, dict) or not isinstance(obj.get("format"), str) \
            or obj["format"] != FORMAT:
        raise DataFormatError(f"{path}: not an evsmap training checkpoint (no \"format\": "
                              f"\"{FORMAT}\")")
    version = obj.get("version")
    if type(version) is not int or version != VERSION:
        shown = repr(version) if isinstance(version, (int, float, str)) or version is None \
            else f"a {type(version).__name__}"
        raise DataFormatError(f"{path}: training checkpoint version {shown}, this evsmap reads "
                              f"version {VERSION}")
    problem = _structure_problem(obj)
    if problem:
        raise DataFormatError(f"{path}: a damaged training checkpoint ({problem})")
    return obj


_FIELDS: dict[str, type | tuple[type, ...]] = {
    "state_dict": dict, "card": dict, "optimizer": dict, "scheduler": dict, "rng": dict,
    "epoch": int, "recipe": dict, "run": dict, "history": list}


def _structure_problem(obj: dict[str, Any]) -> str | None:
    """What a resumed run would trip over, in words (None: nothing)."""
    for key, kind in _FIELDS.items():
        value = obj.get(key)
        if not isinstance(value, kind) or isinstance(value, bool):
            return f"{key!r} is {_kind(value)}"
    for key in ("best", "scaler", "backends"):
        if obj.get(key) is not None and not isinstance(obj[key], dict):
            return f"{key!r} is {_kind(obj[key])}"
    if obj["epoch"] < 0:
        return f"'epoch' is {obj['epoch']}"
    if not all(isinstance(k, str) and isinstance(v, torch.Tensor)
               for k, v in obj["state_dict"].items()):
        return "'state_dict' is not a table of tensors"
    backends = obj.get("backends")
    if backends is not None and not all(
            isinstance(backends.get(k), bool) for k in BACKEND_FLAGS):
        return "'backends' lacks torch's algorithm flags"
    run = obj["run"]
    if not isinstance(run.get("model"), str) or not isinstance(run.get("options"), dict):
        return "'run' lacks the model name or its options"
    rng = obj["rng"]
    numpy_state = rng.get("numpy")
    python_state = rng.get("python")
    if not isinstance(rng.get("torch"), torch.Tensor) or rng["torch"].dtype != torch.uint8 \
            or not isinstance(rng.get("cuda", []), list):
        return "'rng' lacks torch's generator state"
    if not isinstance(numpy_state, dict) or not isinstance(numpy_state.get("key"), list) \
            or not all(isinstance(numpy_state.get(k), int) for k in ("pos", "has_gauss")) \
            or not isinstance(numpy_state.get("gauss"), float) \
            or not isinstance(numpy_state.get("bit_generator"), str):
        return "'rng' lacks numpy's generator state"
    if not isinstance(python_state, (list, tuple)) or len(python_state) != 3 \
            or not isinstance(python_state[1], (list, tuple)):
        return "'rng' lacks Python's generator state"
    try:  # restored into throwaway generators: the global ones are set only when resuming
        torch.Generator().set_state(rng["torch"])
        np.random.RandomState().set_state(  # noqa: NPY002
            {"bit_generator": numpy_state["bit_generator"],
             "state": {"key": np.asarray(numpy_state["key"], dtype=np.uint32),
                       "pos": numpy_state["pos"]},
             "has_gauss": numpy_state["has_gauss"], "gauss": numpy_state["gauss"]})
        random.Random().setstate((python_state[0], tuple(python_state[1]), python_state[2]))
    except (RuntimeError, ValueError, TypeError, OverflowError, IndexError, KeyError) as exc:
        return f"'rng' holds a generator state that does not restore: {' '.join(str(exc).split())}"
    return None


def _kind(value: Any) -> str:
    return "missing" if value is None else f"a {type(value).__name__}"


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


# -- torch's algorithm flags -----------------------------------------------------------------------

BACKEND_FLAGS = ("cudnn_enabled", "cudnn_benchmark", "cudnn_deterministic", "cudnn_allow_tf32",
                 "matmul_allow_tf32", "deterministic_algorithms", "deterministic_warn_only")
"""torch's process-wide switches that choose the algorithms of a run (and so its bits on a GPU):
cuDNN on or off, its autotuner, deterministic kernels, TF32 in convolutions and matmuls, torch's
deterministic-algorithms mode."""


def backend_flags() -> dict[str, bool]:
    """The current values of :data:`BACKEND_FLAGS` (they exist on CPU builds too)."""
    cudnn = torch.backends.cudnn
    return {"cudnn_enabled": bool(cudnn.enabled), "cudnn_benchmark": bool(cudnn.benchmark),
            "cudnn_deterministic": bool(cudnn.deterministic),
            "cudnn_allow_tf32": bool(cudnn.allow_tf32),
            "matmul_allow_tf32": bool(torch.backends.cuda.matmul.allow_tf32),
            "deterministic_algorithms": torch.are_deterministic_algorithms_enabled(),
            "deterministic_warn_only": torch.is_deterministic_algorithms_warn_only_enabled()}


def set_backend_flags(flags: dict[str, bool]) -> None:
    """Set what :func:`backend_flags` returned."""
    cudnn = torch.backends.cudnn
    cudnn.enabled, cudnn.benchmark = flags["cudnn_enabled"], flags["cudnn_benchmark"]
    cudnn.deterministic, cudnn.allow_tf32 = flags["cudnn_deterministic"], \
        flags["cudnn_allow_tf32"]
    torch.backends.cuda.matmul.allow_tf32 = flags["matmul_allow_tf32"]
    torch.use_deterministic_algorithms(flags["deterministic_algorithms"],
                                       warn_only=flags["deterministic_warn_only"])


def derived_seed(*parts: int) -> int:
    """A 63-bit seed from integers (the run's seed, an epoch, a rank), by numpy's SeedSequence."""
    words = np.random.SeedSequence([int(p) for p in parts]).generate_state(2, dtype=np.uint32)
    return (int(words[0]) << 31) ^ int(words[1])


def seed_everything(seed: int) -> None:
    """Seed torch (CPU and every CUDA device), numpy's global and Python's generators."""
    random.seed(seed)
    np.random.seed(seed % 2**32)  # noqa: NPY002  (the global generator others may use)
    torch.manual_seed(seed)


__all__ = ["BACKEND_FLAGS", "BEST", "CHECKPOINT", "FORMAT", "LAST", "LOG", "LOG_COLUMNS", "RUN",
           "VERSION", "atomic_save", "backend_flags", "cpu_state", "derived_seed",
           "load_checkpoint", "log_csv", "read_weights_file", "rng_state", "save_weights",
           "seed_everything", "set_backend_flags", "set_rng_state"]
