"""Loading trained weights (a state dict saved with ``torch.save``) into a network, with errors
that name the file and every mismatched key or shape."""

from __future__ import annotations

import pickle
from os import PathLike
from pathlib import Path

import torch
from torch import nn

from evsmap.errors import DataFormatError

_WRAPPER_KEYS = ("state_dict", "model_state_dict", "model", "net")
_SHOW = 8


def _unwrap(obj: object, path: Path) -> dict[str, torch.Tensor]:
    if isinstance(obj, dict):
        for key in _WRAPPER_KEYS:
            if key in obj and isinstance(obj[key], dict):
                obj = obj[key]
                break
    if not isinstance(obj, dict) or not all(isinstance(v, torch.Tensor) for v in obj.values()):
        raise DataFormatError(
            f"{path}: not a state dict (expected a dict of tensors, optionally under one of "
            f"the keys {', '.join(_WRAPPER_KEYS)})")
    # checkpoints saved from nn.DataParallel / DistributedDataParallel prefix every key
    if obj and all(k.startswith("module.") for k in obj):
        obj = {k[len("module."):]: v for k, v in obj.items()}
    return obj


def _listing(names: list[str]) -> str:
    more = f" and {len(names) - _SHOW} more" if len(names) > _SHOW else ""
    return ", ".join(names[:_SHOW]) + more


def load_weights(module: nn.Module, path: str | PathLike[str]) -> nn.Module:
    """Load the state dict in ``path`` into ``module`` (strictly) and return ``module``.

    Raises:
        DataFormatError: the file is missing, unreadable, not a state dict, or its keys or
            shapes do not match the network (the message lists them).
    """
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(f"{path}: weights file not found")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, OSError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise DataFormatError(f"{path}: cannot read weights ({first})") from None
    state = _unwrap(obj, path)
    own = module.state_dict()
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    shapes = sorted(
        f"{k} (file {tuple(state[k].shape)}, network {tuple(own[k].shape)})"
        for k in set(own) & set(state) if state[k].shape != own[k].shape)
    problems = []
    if missing:
        problems.append(f"missing keys: {_listing(missing)}")
    if unexpected:
        problems.append(f"unexpected keys: {_listing(unexpected)}")
    if shapes:
        problems.append(f"shape mismatch: {_listing(shapes)}")
    if problems:
        raise DataFormatError(
            f"{path}: weights do not fit {type(module).__name__} - " + "; ".join(problems))
    module.load_state_dict(state, strict=True)
    return module
