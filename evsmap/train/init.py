"""``--init``: encoder weights (an ImageNet backbone, another network's encoder) loaded into the
encoders of a network before training, with a report of what was and was not loaded.

The file is read as ``--weights`` reads one (weights-only; a wrapper key such as
``state_dict`` and DataParallel's ``module.`` removed; the official ESANet and FC-HarDNet release
layouts renamed to evsmap's keys, :mod:`evsmap.segmenters.official`). Its keys are then tried in
up to three namings: as they are; HarDNet's ``base.N`` names through the FC-HarDNet key table
(ImageNet HarDNet backbones and FC-HarDNet checkpoints without their decoder); torchvision
ResNet names (``conv1``, ``layer1.0...``) through the ESANet key table.

The network's encoders are its top-level modules whose name contains ``encoder``
(``rgb_encoder`` and ``depth_encoder`` of FEAGNet, ``encoder_rgb`` / ``encoder_depth`` of ESANet,
``encoder`` of FC-HarDNet). For each encoder, the naming and the key prefix of the file (e.g.
``encoder.``, ``rgb_encoder.`` or none) that fit the most of its tensors are chosen; a tensor
loads when its shape matches. A first convolution with one input channel (a depth encoder)
takes the file's 3-channel kernel summed over its input channels, as ESANet initialises its
depth encoder from ImageNet weights. Everything else keeps its initialisation.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from os import PathLike
from typing import Any

import torch
from torch import nn

from evsmap.errors import EvsmapError

_SHOW = 8


@dataclass
class EncoderLoad:
    """What one encoder received.

    Attributes:
        encoder: the network's module (``rgb_encoder``).
        source: where in the file its tensors came from (the prefix and the naming).
        loaded: the encoder's tensors that were loaded (names relative to the encoder).
        summed: those loaded from a kernel summed over its input channels.
        mismatched: ``name (file shape, network shape)`` of name matches not loaded.
        total: tensors of the encoder.
    """

    encoder: str
    source: str
    loaded: list[str]
    summed: list[str]
    mismatched: list[str]
    total: int


@dataclass
class InitReport:
    """What ``--init FILE`` loaded (see the module notes)."""

    file: str
    layout: str
    file_tensors: int
    encoders: list[EncoderLoad]
    unused: list[str] = field(default_factory=list)
    """The file's tensors (its own names) that went nowhere."""
    untouched: dict[str, int] = field(default_factory=dict)
    """Tensors of the network left at their initialisation, by top-level module."""
    used: set[str] = field(default_factory=set, repr=False)
    """The file's tensors (its own names) that were loaded."""

    @property
    def loaded(self) -> int:
        return sum(len(e.loaded) for e in self.encoders)

    def as_dict(self) -> dict[str, Any]:
        return {
            "file": self.file, "layout": self.layout, "file_tensors": self.file_tensors,
            "loaded": self.loaded,
            "encoders": [{"encoder": e.encoder, "source": e.source, "loaded": len(e.loaded),
                          "total": e.total, "summed": list(e.summed),
                          "mismatched": list(e.mismatched)} for e in self.encoders],
            "unused": len(self.unused), "unused_first": self.unused[:_SHOW],
            "untouched": dict(self.untouched),
        }

    def lines(self) -> list[str]:
        out = [f"--init {self.file} ({self.layout}, {self.file_tensors} tensors): loaded "
               f"{self.loaded} tensors"]
        for e in self.encoders:
            line = f"  {e.encoder}: {len(e.loaded)} of {e.total} tensors from {e.source}"
            if e.summed:
                line += f"; summed over input channels: {', '.join(e.summed)}"
            out.append(line)
            if e.mismatched:
                out.append(f"    not loaded, shapes differ: {len(e.mismatched)} "
                           f"({_listing(e.mismatched)})")
            missing = e.total - len(e.loaded)
            if missing and not e.mismatched:
                out.append(f"    {missing} tensors of {e.encoder} not in the file")
        if self.unused:
            groups = _groups(self.unused, self.used)
            out.append(f"  not loaded from the file: {len(self.unused)} tensors ("
                       + ", ".join(f"{g}: {n}" for g, n in groups.most_common()) + ")")
        else:
            out.append("  every tensor of the file was loaded")
        if self.untouched:
            out.append(f"  left at their initialisation: {sum(self.untouched.values())} tensors "
                       f"(" + ", ".join(f"{g}: {n}" for g, n in self.untouched.items()) + ")")
        return out


def _listing(names: list[str]) -> str:
    more = f" and {len(names) - _SHOW} more" if len(names) > _SHOW else ""
    return ", ".join(names[:_SHOW]) + more


def _groups(keys: list[str], used: set[str]) -> Counter:
    """Counts of ``keys`` by top-level module (``head.*``), by the first two levels
    (``encoder.blocks.*``) where part of that module was used."""
    used_tops = {k.split(".")[0] for k in used}
    out: Counter = Counter()
    for key in keys:
        parts = key.split(".")
        head = parts[:2] if parts[0] in used_tops and len(parts) > 2 else parts[:1]
        out[".".join(head) + ".*"] += 1
    return out


def _renamed(state: dict[str, torch.Tensor], table: dict[str, str], prefix: str = ""
             ) -> dict[str, tuple[str, torch.Tensor]]:
    out = {}
    for key, tensor in state.items():
        module, _, leaf = key.rpartition(".")
        target = table.get(prefix + module)
        if target is not None:
            out[f"{target}.{leaf}"] = (key, tensor)
    return out


def _namings(state: dict[str, torch.Tensor]) -> list[tuple[str, dict[str, tuple[str, Any]]]]:
    """(naming, {name: (the file's name, tensor)}) for each way of reading the file's keys."""
    from evsmap.segmenters.official import esanet_table, fchardnet_table

    out: list[tuple[str, dict[str, tuple[str, Any]]]] = [
        ("", {k: (k, v) for k, v in state.items()})]
    if any(k.startswith("base.") for k in state):
        renamed = _renamed(state, fchardnet_table())
        if renamed:
            out.append((" (HarDNet base.N names, FC-HarDNet key table)", renamed))
    if "conv1.weight" in state and any(k.startswith("layer1.") for k in state):
        renamed = _renamed(state, esanet_table(), prefix="encoder_rgb.")
        if renamed:
            out.append((" (torchvision ResNet names, ESANet key table)", renamed))
    return out


def _prefixes(keys) -> set[str]:
    out = {""}
    for key in keys:
        parts = key.split(".")
        for n in range(1, min(len(parts) - 1, 3) + 1):
            out.add(".".join(parts[:n]) + ".")
    return out


def _summable(src: torch.Tensor, dst: torch.Tensor) -> bool:
    """A conv kernel (out, C, kh, kw) that fits a one-input-channel conv once summed over C."""
    return (src.ndim == 4 and dst.ndim == 4 and dst.shape[1] == 1 and src.shape[1] > 1
            and src.shape[0] == dst.shape[0] and src.shape[2:] == dst.shape[2:])


def encoder_names(module: nn.Module) -> list[str]:
    return [name for name, child in module.named_children()
            if "encoder" in name and any(True for _ in child.state_dict())]


def load_encoder_weights(module: nn.Module, path: str | PathLike[str]) -> InitReport:
    """Load the encoder tensors of the file at ``path`` into ``module``'s encoders.

    Raises:
        EvsmapError: the network has no encoder, or no tensor of the file fits one (the
            message says what the file holds).
    """
    from evsmap.segmenters.official import LAYOUTS
    from evsmap.segmenters.weights import one_line, read_weights

    converted = read_weights(path)
    state = {k: v for k, v in converted.state.items() if isinstance(v, torch.Tensor)}
    own = module.state_dict()
    encoders = encoder_names(module)
    if not encoders:
        raise EvsmapError(f"--init loads encoder weights, and {type(module).__name__} has no "
                          f"encoder module (a top-level module named *encoder*)")
    namings = _namings(state)
    used: set[str] = set()
    loads: list[EncoderLoad] = []
    plans: list[tuple[str, list[tuple[str, torch.Tensor, bool]]]] = []
    for enc in encoders:
        rel = {k[len(enc) + 1:]: v for k, v in own.items() if k.startswith(enc + ".")}
        best = _best_fit(enc, rel, namings)
        if best is None or best[0][0] == 0:
            continue
        _, how, prefix, exact, summed, mismatched = best
        where = f"'{prefix}*'" if prefix else "the file's top level"
        loads.append(EncoderLoad(
            encoder=enc, source=where + how, loaded=sorted(r for r, _, _ in exact + summed),
            summed=sorted(r for r, _, _ in summed), mismatched=sorted(mismatched),
            total=len(rel)))
        items = [(r, t, False) for r, _, t in exact] + [(r, t, True) for r, _, t in summed]
        plans.append((enc, items))
        used.update(orig for _, orig, _ in exact + summed)
    if not plans:
        sample = _listing(sorted(state)) if state else "no tensors"
        raise EvsmapError(one_line(
            f"{path}: no tensor of the file fits an encoder of {type(module).__name__} "
            f"({', '.join(encoders)}); the file ({LAYOUTS[converted.layout]}) holds {sample}"))
    loaded_keys = _copy_into(own, plans)
    untouched = Counter(k.split(".")[0] for k in own if k not in loaded_keys)
    return InitReport(file=str(path), layout=LAYOUTS[converted.layout], file_tensors=len(state),
                      encoders=loads, unused=sorted(k for k in state if k not in used),
                      untouched=dict(untouched.most_common()), used=used)


_Match = tuple[str, str, torch.Tensor]
"""A tensor of an encoder (name relative to it), the file's name for it, the file's tensor."""


def _best_fit(enc: str, rel: dict[str, torch.Tensor],
              namings: list[tuple[str, dict[str, tuple[str, Any]]]]) -> tuple | None:
    """The naming and key prefix of the file that fit the most of encoder ``enc``'s tensors
    ``rel``: ``((score), how, prefix, exact, summed, mismatched)``; None when the file has
    no prefix at all."""
    from evsmap.segmenters.weights import castable

    best: tuple | None = None
    for how, named in namings:
        for prefix in sorted(_prefixes(named)):
            exact: list[_Match] = []
            summed: list[_Match] = []
            mismatched: list[str] = []
            for key, (orig, tensor) in named.items():
                if not key.startswith(prefix):
                    continue
                r = key[len(prefix):]
                if r not in rel:
                    continue
                if not castable(tensor.dtype, rel[r].dtype):
                    mismatched.append(f"{r} (file {tensor.dtype}, network {rel[r].dtype})")
                elif tensor.shape == rel[r].shape:
                    exact.append((r, orig, tensor))
                elif _summable(tensor, rel[r]):
                    summed.append((r, orig, tensor))
                else:
                    mismatched.append(f"{r} (file {tuple(tensor.shape)}, network "
                                      f"{tuple(rel[r].shape)})")
            score = (len(exact) + len(summed), len(exact), prefix == enc + ".")
            if best is None or score > best[0]:
                best = (score, how, prefix, exact, summed, mismatched)
    return best


def _copy_into(own: dict[str, torch.Tensor],
               plans: list[tuple[str, list[tuple[str, torch.Tensor, bool]]]]) -> set[str]:
    """Copy the planned tensors into the network's state ``own`` (a kernel summed over its
    input channels where marked); returns the keys loaded."""
    loaded_keys: set[str] = set()
    with torch.no_grad():
        for enc, items in plans:
            for r, tensor, sum_channels in items:
                target = own[f"{enc}.{r}"]
                value = tensor.sum(dim=1, keepdim=True) if sum_channels else tensor
                target.copy_(value.to(dtype=target.dtype))
                loaded_keys.add(f"{enc}.{r}")
    return loaded_keys


__all__ = ["EncoderLoad", "InitReport", "encoder_names", "load_encoder_weights"]
