"""``evsmap weights convert``: an official release checkpoint (or any state dict) as an evsmap
weights file with a card.

``evsmap weights convert SRC --out DST [--model NAME] [-o KEY=VALUE ...]`` reads SRC the way
``--weights`` does (weights-only, numpy scalars through an allow-list; the official ESANet and
FC-HarDNet layouts recognised by their keys and renamed, FC-HarDNet's BGR first convolution
turned to RGB - see :mod:`evsmap.segmenters.official`), builds the segmenter (NAME, default the
one the layout is for; options default to the configuration found in the file, ``-o`` overrides
them), loads the tensors into it strictly, and writes with ``torch.save``::

    {"state_dict": {evsmap key: tensor, ...},   # in the network's state_dict() order
     "card": {...}}

DST then loads wherever ``--weights`` is taken (the ``state_dict`` wrapper is one the loader
knows) and is recognised as the ``evsmap`` layout. The card is a flat dict of plain values
(str, int, float, bool, lists), readable with ``weights_only=True``:

``card_version``    1
``model``           registered segmenter name, e.g. ``"fchardnet-70"``
``options``         segmenter options that build the network the file fits, e.g.
                    ``{"dataset": "cityscapes"}`` (pass them as ``-o KEY=VALUE`` with --weights)
``num_classes``     classes of the classifier
``class_names``     the segmenter's class names
``source_file``     file name of SRC (no folder)
``source_sha256``   SHA-256 of the SRC file's bytes
``source_layout``   ``esanet-release``, ``fchardnet-release``, ``evsmap`` or ``plain``
``conversion``      what the conversion did besides renaming (list of sentences)
``evsmap_version``  version of evsmap that wrote the file
``tensors``         number of tensors
``tensors_sha256``  :func:`evsmap.segmenters.weights.tensors_sha256` of the state dict

Later card versions may add keys; readers should ignore keys they do not know.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path
from typing import Any

from evsmap.cli.options import key_value
from evsmap.errors import EvsmapError
from evsmap.version import evsmap_version

CARD_VERSION = 1
_RESERVED = ("weights", "backend", "input_size")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "weights", help="convert official checkpoints to evsmap weights files",
        description="Work with segmenter weights files.")
    actions = p.add_subparsers(dest="action", metavar="ACTION", parser_class=type(p))
    actions.required = True
    c = actions.add_parser(
        "convert", help="write an official release checkpoint as an evsmap weights file",
        description="Read SRC (an official ESANet or FC-HarDNet release file, or any state "
                    "dict), rename it to evsmap's keys, load it strictly into the segmenter and "
                    "write DST: the state dict plus a card (model, options, classes, source "
                    "layout and SHA-256, evsmap version, SHA-256 of the tensors).")
    c.add_argument("source", metavar="SRC", type=Path, help="checkpoint to convert")
    c.add_argument("--out", required=True, type=Path, metavar="DST", help="file to write")
    c.add_argument("--model", metavar="NAME",
                   help="segmenter the weights are for (default: the one the file's layout is "
                        "for; needed for a plain state dict)")
    c.add_argument("-o", "--option", type=key_value, action="append", default=[],
                   metavar="KEY=VALUE",
                   help="a segmenter option, repeatable (default: the configuration found in "
                        "the file, e.g. dataset=cityscapes)")
    c.add_argument("--force", action="store_true", help="overwrite DST")
    c.add_argument("--json", action="store_true", help="print the card as JSON")
    c.set_defaults(run=run_convert)


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()



def convert(source: Path, out: Path, *, model: str | None = None,
            options: dict[str, Any] | None = None, force: bool = False) -> dict[str, Any]:
    """Convert ``source`` to an evsmap weights file ``out``; returns the card.

    Raises:
        EvsmapError: unreadable or unconvertible source, unknown segmenter or options, weights
            that do not fit the segmenter, or ``out`` exists (without ``force``).
    """
    import torch

    from evsmap.registry import SEGMENTERS
    from evsmap.segmenters.weights import load_state, read_weights, tensors_sha256

    if out.exists() and not force:
        raise EvsmapError(f"{out} exists: pass --force to overwrite it")
    if out.exists() and source.exists() and out.resolve() == source.resolve():
        raise EvsmapError(f"--out {out} is the source file: write to another file")
    converted = read_weights(source)
    name = model or converted.segmenter
    if name is None:
        raise EvsmapError(f"{source}: a {converted.describe()} does not say which network it "
                          f"is for: pass --model NAME")
    config = dict(converted.options or {}) if name == converted.segmenter else {}
    config.update(options or {})
    reserved = sorted(set(config) & set(_RESERVED))
    if reserved:
        raise EvsmapError(f"option {reserved[0]} cannot be set here (the file is the weights; "
                          f"backend and input size are chosen when the weights are used)")
    segmenter = SEGMENTERS.create(name, **config)
    module = getattr(segmenter, "module", None)
    if module is None:
        raise EvsmapError(f"{name} is not a network segmenter: it takes no weights")
    load_state(module, converted, source)
    state = {k: converted.state[k] for k in module.state_dict()}
    card = {
        "card_version": CARD_VERSION,
        "model": name,
        "options": config,
        "num_classes": int(segmenter.num_classes),
        "class_names": list(getattr(segmenter, "class_names", ())),
        "source_file": source.name,
        "source_sha256": file_sha256(source),
        "source_layout": converted.layout,
        "conversion": list(converted.notes),
        "evsmap_version": evsmap_version(),
        "tensors": len(state),
        "tensors_sha256": tensors_sha256(state),
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"state_dict": state, "card": card}, out)
    written = read_weights(out)  # the file reads back through the --weights path
    if tensors_sha256(written.state) != card["tensors_sha256"]:  # pragma: no cover
        raise EvsmapError(f"{out}: the tensors read back differ from those written")
    return card


def run_convert(args: argparse.Namespace) -> int:
    card = convert(args.source, args.out, model=args.model, options=dict(args.option),
                   force=args.force)
    if args.json:
        print(json.dumps({"out": str(args.out), "card": card}, indent=2))
        return 0
    opts = " ".join(f"-o {k}={v}" for k, v in card["options"].items())
    print(f"wrote {args.out}: {card['model']} ({card['num_classes']} classes"
          f"{', ' + opts if opts else ''}), {card['tensors']} tensors from a file in the "
          f"{card['source_layout']} layout")
    for note in card["conversion"]:
        print(f"  {note}")
    print(f"  tensors sha256 {card['tensors_sha256']}")
    print(f"use it with: --weights {args.out}" + (f" {opts}" if opts else ""))
    return 0
