"""Loading trained weights (a state dict saved with ``torch.save``) into a network, with errors
that name the file and every mismatched key or shape.

Files are read with ``torch.load(..., weights_only=True)``: tensors and plain containers, plus
an allow-list of exactly the numpy objects that official release files keep in their metadata
(FC-HarDNet's ``best_iou`` is a ``numpy.float64``): ``numpy.core.multiarray.scalar`` (under
numpy 1's and numpy 2's module name), ``numpy.dtype`` and its float64 class. Anything else a
file refers to (a class, a function) is refused with a one-line error; weights are never read
with ``weights_only=False``.

The state dict may be wrapped (``state_dict``, ``model_state_dict``, ``model_state``, ``model``
or ``net``) and prefixed by DataParallel (``module.``). Official release layouts (ESANet,
FC-HarDNet) are recognised by their keys and renamed to evsmap's modules by
:mod:`evsmap.segmenters.official`; then the keys and shapes must match the network exactly.
"""

from __future__ import annotations

import hashlib
import io
import re
from collections.abc import Mapping
from os import PathLike
from pathlib import Path

import torch
from torch import nn

from evsmap.errors import DataFormatError
from evsmap.segmenters.official import (
    EVSMAP,
    LAYOUTS,
    PLAIN,
    Converted,
    check_fits,
    convert_state,
)

_WRAPPER_KEYS = ("state_dict", "model_state_dict", "model_state", "model", "net")
_SHOW = 8
_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def numpy_allowlist() -> list:
    """The numpy objects admitted by ``torch.load(weights_only=True)``: what a pickled
    ``numpy.float64`` refers to, under both spellings of numpy's core module."""
    import importlib

    import numpy as np

    try:
        scalar = importlib.import_module("numpy._core.multiarray").scalar
    except ImportError:  # numpy < 2
        scalar = importlib.import_module("numpy.core.multiarray").scalar
    allowed: list = [np.dtype,
                     (scalar, "numpy.core.multiarray.scalar"),
                     (scalar, "numpy._core.multiarray.scalar")]
    float64 = type(np.dtype(np.float64))  # numpy.dtypes.Float64DType on numpy >= 1.25
    if float64 is not np.dtype:
        allowed.append(float64)
    return allowed


def _reason(exc: BaseException) -> str:
    """One line out of torch's multi-paragraph weights-only message."""
    text = _ANSI.sub("", str(exc)).strip()
    allowed = "evsmap reads tensors, plain containers and numpy float64 scalars only"
    refused = re.search(r"(?:Unsupported global: GLOBAL|unsupported GLOBAL) (\S+)", text)
    if refused:
        return f"it refers to {refused.group(1)}, which a weights file may not hold: {allowed}"
    built = re.search(r"but got <class '([^']+)'>", text)
    if built:
        return f"it builds a {built.group(1)}, which a weights file may not hold: {allowed}"
    if "WeightsUnpickler error:" in text:
        detail = text.split("WeightsUnpickler error:", 1)[1]
        detail = " ".join(detail.split("Check the documentation")[0].split())
        return f"refused by the weights-only reader: {detail}" if detail else \
            "refused by the weights-only reader"
    if text.startswith("Weights only load failed"):  # the advice, then the reason
        paragraphs = [p for p in re.split(r"\n\s*\n", text)[1:]
                      if p.strip() and not p.lstrip().startswith("Check the documentation")]
        if paragraphs:
            return f"refused by the weights-only reader: {' '.join(paragraphs[0].split())}"
    return text.splitlines()[0] if text else type(exc).__name__


def read_checkpoint(path: str | PathLike[str], *, mmap: bool = False) -> object:
    """The object in a weights file, read with ``weights_only=True`` and the numpy allow-list
    (``mmap``: tensors left on disk where the format allows it).

    Raises:
        DataFormatError: the file is missing or cannot be read (one line).
    """
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(f"{path}: weights file not found")
    check_checkpoint_head(path)
    try:
        obj = torch_load(path, mmap=mmap)
    except MemoryError:
        raise
    except Exception as exc:  # any file may be given: every failure is one line, no traceback
        raise DataFormatError(f"{path}: cannot read weights ({one_line_reason(exc)})") from None
    check_nesting(obj, path)
    return obj


CHECKPOINT_HEADS = (b"PK\x03\x04", b"\x80")
"""How a file ``torch.save`` wrote begins: a zip archive (the format since torch 1.6), or a
pickle (protocol 2 or later: the legacy format)."""


def check_checkpoint_head(path: Path) -> None:
    """Refuse a file that is not a PyTorch checkpoint (a text file, an image, a safetensors
    or numpy file) by its first bytes, naming what it starts with, before torch's reader
    fails on it with an unhelpful ``KeyError``."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(16)
    except OSError as exc:
        raise DataFormatError(f"{path}: cannot read weights ({exc.strerror or exc})") from None
    if not head:
        raise DataFormatError(f"{path}: the weights file is empty")
    if not head.startswith(CHECKPOINT_HEADS):
        raise DataFormatError(f"{path}: not a PyTorch checkpoint (a torch.save file is a zip "
                              f"archive; this one starts with {head[:8]!r})")


MAX_NESTING = 64
"""How deep a weights file's containers may nest (a state dict, an optimizer's state and a
card need fewer than 10 levels)."""
MAX_ITEMS = 10_000_000
"""How many items a weights file's containers may hold, counting a shared container once per
reference (what a walk over them visits)."""


def check_nesting(obj: object, path: Path) -> None:
    """Refuse containers nested deeper than :data:`MAX_NESTING`, holding themselves, or sharing
    containers so that a walk over them visits more than :data:`MAX_ITEMS` items (a pickle can
    build all three in a few bytes; every later walk over the object - a repr, JSON, the card
    printer - would recurse without end or for ever).

    Raises:
        DataFormatError: naming the file.
    """
    sizes: dict[int, int] = {}
    on_path: set[int] = set()

    class _Refused(Exception):
        pass

    def walk(item: object, depth: int) -> int:
        if isinstance(item, dict):
            children = [*item.keys(), *item.values()]
        elif isinstance(item, (list, tuple, set, frozenset)):
            children = list(item)
        else:
            return 1
        key = id(item)
        if key in on_path:
            raise _Refused("a container that holds itself")
        if key in sizes:
            return sizes[key]
        if depth > MAX_NESTING:
            raise _Refused(f"containers nested more than {MAX_NESTING} deep")
        on_path.add(key)
        total = 1
        for child in children:
            total += walk(child, depth + 1)
            if total > MAX_ITEMS:
                raise _Refused(f"containers that expand to more than {MAX_ITEMS:,} items")
        on_path.discard(key)
        sizes[key] = total
        return total

    try:
        walk(obj, 0)
    except _Refused as exc:
        raise DataFormatError(f"{path}: cannot read weights (it holds {exc})") from None


def torch_load(path: Path, *, mmap: bool = False) -> object:
    """``torch.load(weights_only=True)`` with the numpy allow-list.

    A file in the legacy (non-zip) format is read into memory first: the pickle's claimed
    string and byte lengths are then bounded by the file's size (reading a file object
    allocates a claimed length before it finds the file shorter). ``mmap`` maps a zip file's
    tensors instead of reading them.
    """
    with torch.serialization.safe_globals(numpy_allowlist()):
        with path.open("rb") as fh:
            zipped = fh.read(4) == b"PK\x03\x04"
        if not zipped:
            return torch.load(io.BytesIO(path.read_bytes()), map_location="cpu",
                              weights_only=True)
        return torch.load(path, map_location="cpu", weights_only=True, mmap=mmap)


def one_line(text: str) -> str:
    """``text`` with line breaks and other unprintable characters escaped (a file's key names
    and card values are any text)."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def one_line_reason(exc: BaseException) -> str:
    """Why torch's reader refused a file, in one line: :func:`_reason` without torch's advice
    paragraphs, with the exception's type where its message alone says nothing (a bare
    ``KeyError`` or ``IndexError`` out of a corrupt pickle)."""
    text = " ".join(_reason(exc).split())
    for cut in (". This is an internal", ". Check the documentation", ". If you"):
        text = text.split(cut)[0]
    name = type(exc).__name__
    if " " not in text:
        return f"{name}: {text}" if text and text != name else f"{name} (corrupt file)"
    return text


def _unwrap(obj: object, path: Path) -> dict[str, torch.Tensor]:
    if isinstance(obj, dict):
        for key in _WRAPPER_KEYS:
            if key in obj and isinstance(obj[key], dict):
                obj = obj[key]
                break
    if not isinstance(obj, dict) or not all(isinstance(k, str) and isinstance(v, torch.Tensor)
                                            for k, v in obj.items()):
        raise DataFormatError(
            f"{path}: not a state dict (expected a dict of names to tensors, optionally under "
            f"one of the keys {', '.join(_WRAPPER_KEYS)})")
    # checkpoints saved from nn.DataParallel / DistributedDataParallel prefix every key
    if obj and all(k.startswith("module.") for k in obj):
        obj = {k[len("module."):]: v for k, v in obj.items()}
    return obj


def read_weights(path: str | PathLike[str]) -> Converted:
    """The state dict in ``path`` under evsmap's key names, with its source layout.

    Raises:
        DataFormatError: the file is missing, unreadable, not a state dict, or in an official
            layout with keys evsmap has no name for.
    """
    path = Path(path)
    obj = read_checkpoint(path)
    state = _unwrap(obj, path)
    card = obj.get("card") if isinstance(obj, dict) else None
    card = card if isinstance(card, dict) else None
    _check_card(card, path)
    return convert_state(state, source=str(path), card=card)


def _check_card(card: dict | None, path: Path) -> None:
    """The card fields the loader acts on (``model``, ``options``) must have their types."""
    if card is None:
        return
    model, options = card.get("model"), card.get("options")
    if model is not None and not isinstance(model, str):
        raise DataFormatError(f"{path}: the card's 'model' must be a segmenter name (a string), "
                              f"not a {type(model).__name__}")
    if options is not None and not (isinstance(options, dict)
                                    and all(isinstance(k, str) for k in options)):
        raise DataFormatError(f"{path}: the card's 'options' must be a table of option names "
                              f"to values, not a {type(options).__name__}")


def _listing(names: list[str]) -> str:
    more = f" and {len(names) - _SHOW} more" if len(names) > _SHOW else ""
    return ", ".join(names[:_SHOW]) + more


def _context(converted: Converted, state: Mapping[str, torch.Tensor],
             own: Mapping[str, torch.Tensor]) -> str:
    """What to add to a list of mismatches: where the file's keys came from."""
    if converted.layout not in (PLAIN, EVSMAP):
        return f" (the file is the {converted.describe()}, renamed to evsmap's keys)"
    if converted.layout == EVSMAP:
        return f" (the file is an {converted.describe()})"
    if state and not set(state) & set(own):
        return (f"; no key of the file is a key of the network, and the file is in none of "
                f"the official layouts evsmap converts ({LAYOUTS['esanet-release']}; "
                f"{LAYOUTS['fchardnet-release']})")
    return ""


def load_state(module: nn.Module, converted: Converted, source: str | PathLike[str]) -> nn.Module:
    """Load a state dict read by :func:`read_weights` into ``module`` (strictly).

    Raises:
        DataFormatError: an official checkpoint of another network or configuration, or keys
            or shapes that do not match the network (the message lists them).
    """
    check_fits(converted, module, str(source))
    state = converted.state
    own = module.state_dict()
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    shapes = sorted(
        f"{k} (file {tuple(state[k].shape)}, network {tuple(own[k].shape)})"
        for k in set(own) & set(state) if state[k].shape != own[k].shape)
    dtypes = sorted(
        f"{k} (file {state[k].dtype}, network {own[k].dtype})"
        for k in set(own) & set(state) if not castable(state[k].dtype, own[k].dtype))
    problems = []
    if missing:
        problems.append(f"missing keys: {_listing(missing)}")
    if unexpected:
        problems.append(f"unexpected keys: {_listing(unexpected)}")
    if shapes:
        problems.append(f"shape mismatch: {_listing(shapes)}")
    if dtypes:
        problems.append(f"dtype mismatch: {_listing(dtypes)}")
    if problems:
        raise DataFormatError(one_line(
            f"{source}: weights do not fit {type(module).__name__} - " + "; ".join(problems)
            + _context(converted, state, own)))
    module.load_state_dict(state, strict=True)
    return module


def castable(file: torch.dtype, network: torch.dtype) -> bool:
    """Whether a file's tensor of dtype ``file`` loads into the network's ``network`` tensor
    without losing its meaning: real numbers are cast (half precision, double, a counter saved
    as a float), complex and bool tensors only load into their own dtype."""
    if file.is_complex or file == torch.bool or network.is_complex or network == torch.bool:
        return file == network
    return True


def load_weights(module: nn.Module, path: str | PathLike[str]) -> nn.Module:
    """Load the state dict in ``path`` into ``module`` (strictly) and return ``module``.

    Official release checkpoints (ESANet, FC-HarDNet) are converted on the way.

    Raises:
        DataFormatError: the file is missing, unreadable, not a state dict, an official
            checkpoint of another network or configuration, or its keys or shapes do not match
            the network (the message lists them).
    """
    return load_state(module, read_weights(path), path)


def tensors_sha256(state: Mapping[str, torch.Tensor]) -> str:
    """SHA-256 over the tensors of a state dict: for each key in sorted order, the key, dtype,
    shape and the raw bytes (C order)."""
    digest = hashlib.sha256()
    for key in sorted(state):
        tensor = state[key].detach().cpu().contiguous()
        digest.update(f"{key}\0{tensor.dtype}\0{tuple(tensor.shape)}\0".encode())
        digest.update(tensor.reshape(-1).view(torch.uint8).numpy().tobytes())
    return digest.hexdigest()
