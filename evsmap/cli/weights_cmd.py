"""``evsmap weights``: evsmap weights files and their cards.

``evsmap weights list [PATH ...] [--json]`` lists the weights files under each PATH (a folder,
searched recursively for ``*.pt`` / ``*.pth``, hidden folders skipped; or a file of any name),
one line per file: model and options, dataset, classes, measured val/test mIoU and size from its
card; a file without a card is named by its layout (plain state dict, official release); an
unreadable file by its one-line reason. Files are opened with ``torch.load(weights_only=True,
mmap=True)``: only the pickled structure is read, the tensors stay on disk (files in the legacy
non-zip format, which cannot be memory-mapped, are read whole).

``evsmap weights show FILE [--json]`` prints the whole card and checks the tensors against it:
the SHA-256 over the tensors is recomputed and compared with the card's ``tensors_sha256``
(exit status 1 when they differ).

``evsmap weights convert SRC --out DST [--model NAME] [-o KEY=VALUE ...]`` reads SRC the way
``--weights`` does (weights-only, numpy scalars through an allow-list; the official ESANet and
FC-HarDNet layouts recognised by their keys and renamed, FC-HarDNet's BGR first convolution
turned to RGB - see :mod:`evsmap.segmenters.official`), builds the segmenter (NAME, default the
one the layout is for; options default to the configuration found in the file, ``-o`` overrides
them), loads the tensors into it strictly, and writes with ``torch.save``::

    {"state_dict": {evsmap key: tensor, ...},   # in the network's state_dict() order
     "card": {...}}

DST then loads wherever ``--weights`` is taken (the ``state_dict`` wrapper is one the loader
knows) and is recognised as the ``evsmap`` layout. The card
(:func:`evsmap.segmenters.cards.make_card`) is a flat dict of plain values (str, int, float,
bool, None, lists), readable with ``weights_only=True``:

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
``git_commit``      commit of the evsmap checkout that wrote it (``+dirty`` with uncommitted
                    changes; None outside a git checkout)
``tensors``         number of tensors
``tensors_sha256``  :func:`evsmap.segmenters.weights.tensors_sha256` of the state dict

Cards written by ``evsmap train`` add the dataset (``dataset``: the folder or name trained on,
``reader``: its reader), splits, recipe, ``epochs`` and the measured ``val_miou`` /
``test_miou`` (fractions). Later card versions may add keys; readers ignore keys they do not
know, and every key but ``model`` may be missing.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import textwrap
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from evsmap.cli.options import key_value
from evsmap.errors import EvsmapError
from evsmap.segmenters.cards import (
    card_dataset,
    card_get,
    card_miou,
    card_spec,
    find_weights_files,
    format_options,
    inspect_weights,
    open_weights,
)

_RESERVED = ("weights", "backend", "input_size")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "weights", help="list, show and convert segmenter weights files",
        description="Work with segmenter weights files and their cards.")
    actions = p.add_subparsers(dest="action", metavar="ACTION", parser_class=type(p))
    actions.required = True
    ls = actions.add_parser(
        "list", help="list the weights files in a folder with their cards",
        description="List the weights files under each PATH (a folder, searched recursively "
                    "for *.pt and *.pth, or a file): model and options, dataset, classes, "
                    "val/test mIoU and size from the card; files without a card by their "
                    "layout, unreadable files by their reason. Tensors are not read.")
    ls.add_argument("paths", nargs="*", type=Path, default=[Path(".")], metavar="PATH",
                    help="folder or file (default: the current folder)")
    ls.add_argument("--json", action="store_true", help="one JSON object per file, in a list")
    ls.set_defaults(run=run_list)
    show = actions.add_parser(
        "show", help="print a weights file's card and verify its tensors",
        description="Print the card of FILE and recompute the SHA-256 of its tensors: exit "
                    "status 1 when they differ from the card's tensors_sha256.")
    show.add_argument("file", type=Path, metavar="FILE", help="weights file")
    show.add_argument("--json", action="store_true", help="print the card and check as JSON")
    show.set_defaults(run=run_show)
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
    c.add_argument("--overwrite", "--force", dest="overwrite", action="store_true",
                   help="replace an existing DST (once the new file is complete)")
    c.add_argument("--json", action="store_true", help="print the card as JSON")
    c.set_defaults(run=run_convert)


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def format_size(size: int) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if size >= scale:
            return f"{size / scale:.1f} {unit}"
    return f"{size} B"


def _plain(value: Any) -> Any:
    """A card's data as JSON takes it: keys as strings (a card may hold any key the
    weights-only reader admits: numbers, tuples)."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def _percent(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f} %"


# ----------------------------------------------------------------------------- list, show
def run_list(args: argparse.Namespace) -> int:
    files = [inspect_weights(p) for p in find_weights_files(args.paths)]
    if args.json:
        print(json.dumps(_plain([f.as_dict() for f in files]), indent=2, default=str))
        return 0
    if not files:
        where = ", ".join(str(p) for p in args.paths)
        print(f"no weights files (*.pt, *.pth) under {where}")
        return 0
    header = ["FILE", "MODEL", "DATASET", "CLASSES", "VAL mIoU", "TEST mIoU", "SIZE"]
    rows: list[list[str] | tuple[str, str]] = []
    for f in files:
        if f.card is not None and f.error is None:
            classes = card_get(f.card, "num_classes")
            rows.append([str(f.path), card_spec(f.card) + (" [checkpoint]" if f.checkpoint
                                                           else ""),
                         card_dataset(f.card) or "-", "-" if classes is None else str(classes),
                         _percent(card_miou(f.card, "val")),
                         _percent(card_miou(f.card, "test")), format_size(f.size)])
        else:
            rows.append((str(f.path), f"{f.describe()}, {format_size(f.size)}"))
    table = [header] + [r for r in rows if isinstance(r, list)]
    widths = [max(len(r[i]) for r in table) for i in range(len(header))]
    widths[0] = max(widths[0], *(len(r[0]) for r in rows))
    right = {3, 4, 5, 6}

    def line(cells: list[str]) -> str:
        return "  ".join(c.rjust(w) if i in right else c.ljust(w)
                         for i, (c, w) in enumerate(zip(cells, widths, strict=True))).rstrip()

    print(line(header))
    for r in rows:
        print(line(r) if isinstance(r, list) else f"{r[0].ljust(widths[0])}  {r[1]}")
    carded = sum(f.card is not None and f.error is None for f in files)
    broken = sum(f.error is not None for f in files)
    print(f"{len(files)} file{'s' if len(files) != 1 else ''}: {carded} with a card, "
          f"{len(files) - carded - broken} without, {broken} unreadable")
    return 0


def verify_tensors(card: Mapping[str, Any] | None,
                   state: Mapping[str, Any]) -> tuple[bool | None, str, str]:
    """``(verified, message, sha256)``: the state dict's :func:`tensors_sha256` against the
    card's ``tensors_sha256`` (``verified`` None when there is nothing to compare with)."""
    from evsmap.segmenters.weights import tensors_sha256

    digest = tensors_sha256(state)
    expected = card_get(card, "tensors_sha256")
    if card is None:
        return None, f"{len(state)} tensors, sha256 {digest} (no card to check against)", digest
    if not isinstance(expected, str):
        return None, (f"{len(state)} tensors, sha256 {digest} (the card holds no "
                      f"tensors_sha256 to check against)"), digest
    if digest == expected:
        return True, f"tensors match the card ({len(state)} tensors, sha256 {digest})", digest
    count = card_get(card, "tensors")
    counted = (f"; the card counts {count} tensors, the file holds {len(state)}"
               if isinstance(count, int) and count != len(state) else "")
    return False, (f"tensors differ from the card: the file was changed after it was written "
                   f"(card sha256 {expected}, tensors {digest}{counted})"), digest


def _value_text(key: str, value: Any) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and "miou" in key.lower():
        return f"{value:.4f} ({100 * value:.2f} %)"
    if isinstance(value, (list, tuple)):
        return ", ".join(_value_text(key, v) for v in value) if value else "(none)"
    if isinstance(value, Mapping):
        return format_options(value).replace(",", ", ") or "{}"
    return str(value)


def pretty_card(card: Mapping[str, Any], indent: int = 2, width: int = 100) -> list[str]:
    """The card as aligned ``key  value`` lines; nested tables indented below their key, long
    values wrapped."""
    lines: list[str] = []
    if not card:
        return [" " * indent + "(empty)"]
    keys = max(len(str(k)) for k in card)
    for key, value in card.items():
        head = " " * indent + str(key).ljust(keys) + "  "
        nested = isinstance(value, Mapping) and bool(value) and (
            len(value) > 4 or any(isinstance(v, (Mapping, list, tuple)) for v in value.values()))
        if nested:
            lines.append(" " * indent + str(key))
            lines += pretty_card(value, indent + 2, width)
            continue
        text = _value_text(str(key), value)
        lines += textwrap.wrap(text, width=max(40, width - len(head)), initial_indent=head,
                               subsequent_indent=" " * len(head), break_on_hyphens=False) \
            or [head.rstrip()]
    return lines


def _weights_file(path: Path, what: str) -> None:
    """Refuse a folder given where a weights file goes (``what``: how the command names it)."""
    if path.is_dir():
        raise EvsmapError(f"{what}{path}: is a folder, not a weights file (`evsmap weights "
                          f"list DIR` lists the weights files in a folder)")


def run_show(args: argparse.Namespace) -> int:
    _weights_file(args.file, "")
    info, state = open_weights(args.file)
    verified, message, digest = verify_tensors(info.card, state)
    if args.json:
        shown = {**info.as_dict(), "tensors_sha256": digest, "verified": verified,
                 "verification": message}
        print(json.dumps(_plain(shown), indent=2, default=str))
        return 1 if verified is False else 0
    print(f"{info.path} ({format_size(info.size)}): {info.describe()}")
    if info.card is not None:
        print("card:")
        print("\n".join(pretty_card(info.card)))
    print(message)
    return 1 if verified is False else 0


# ----------------------------------------------------------------------------- convert
def convert(source: Path, out: Path, *, model: str | None = None,
            options: dict[str, Any] | None = None, overwrite: bool = False) -> dict[str, Any]:
    """Convert ``source`` to an evsmap weights file ``out``; returns the card.

    ``out`` is claimed first (:func:`evsmap.cli.outputs.claim_outputs`: an existing file is
    refused without ``overwrite``, a folder or an unwritable place always), before the source
    is read.

    Raises:
        EvsmapError: unreadable or unconvertible source, unknown segmenter or options, weights
            that do not fit the segmenter, or an ``out`` that is taken or cannot be written.
    """
    from evsmap.cli.outputs import Output, claim_outputs

    _weights_file(source, "SRC ")  # the checks first: they need no torch, which takes seconds
    if source.exists() and Path(os.path.abspath(out)) == Path(os.path.abspath(source)) or \
            out.exists() and source.exists() and out.resolve() == source.resolve():
        raise EvsmapError(f"--out {out} is the source file: write to another file")
    claim_outputs([Output("--out", out)], overwrite=overwrite)

    import torch

    from evsmap.registry import SEGMENTERS
    from evsmap.segmenters.cards import make_card
    from evsmap.segmenters.weights import load_state, read_weights, tensors_sha256
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
    # the name and options may come from the file's card: a refusal names the file
    where = f"--model {name}" if model else f"{source}: the file is for {name}"
    try:
        segmenter = SEGMENTERS.create(name, **config)
    except EvsmapError as exc:
        raise EvsmapError(f"{where}: {exc}") from None
    except (TypeError, ValueError, OverflowError) as exc:  # a factory refusing an option
        raise EvsmapError(f"{where}: {' '.join(str(exc).split())}") from None
    module = segmenter.module
    if module is None:
        raise EvsmapError(f"{where}: {name} is not a network segmenter: it takes no weights")
    load_state(module, converted, source)
    state = {k: converted.state[k] for k in module.state_dict()}
    card = make_card(model=name, options=config, num_classes=int(segmenter.num_classes),
                     class_names=list(segmenter.class_names), state_dict=state,
                     source_file=source.name, source_sha256=file_sha256(source),
                     source_layout=converted.layout, conversion=list(converted.notes))
    out.parent.mkdir(parents=True, exist_ok=True)
    from evsmap.fileio import atomic_write

    with atomic_write(out, "wb") as fh:  # an older file of that name stays until this is whole
        torch.save({"state_dict": state, "card": card}, fh)
    written = read_weights(out)  # the file reads back through the --weights path
    if tensors_sha256(written.state) != card["tensors_sha256"]:  # pragma: no cover
        raise EvsmapError(f"{out}: the tensors read back differ from those written")
    return card


def run_convert(args: argparse.Namespace) -> int:
    from evsmap.segmenters.weights import one_line

    try:
        card = convert(args.source, args.out, model=args.model, options=dict(args.option),
                       overwrite=args.overwrite)
    except EvsmapError as exc:  # names and options may come from the file: any text
        if one_line(str(exc)) == str(exc):
            raise
        raise EvsmapError(one_line(str(exc))) from None
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
