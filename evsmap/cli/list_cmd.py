"""``evsmap list``: the registered plug-ins."""

from __future__ import annotations

import argparse
import json
from typing import Any

from evsmap.registry import READERS, SEGMENTERS, UPDATERS, Registry


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("list", help="list registered segmenters, updaters and readers",
                       description="List the registered segmenters, map updaters and sequence "
                                   "readers with one-line descriptions.")
    p.add_argument("--json", action="store_true",
                   help='print {"segmenters": [...], "updaters": [...], "readers": [...]}')
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    kinds: dict[str, Registry[Any]] = {"segmenters": SEGMENTERS, "updaters": UPDATERS,
                                       "readers": READERS}
    if args.json:
        print(json.dumps({k: reg.names() for k, reg in kinds.items()}))
        return 0
    for title, reg in kinds.items():
        print(f"{title}:")
        entries = reg.entries()
        if not entries:
            print("  (none registered)")
        width = max((len(e.name) for e in entries), default=0)
        for e in entries:
            print(f"  {e.name:<{width}}  {e.description}")
    _print_cards()
    return 0


def _print_cards() -> None:
    """The model cards (:mod:`evsmap.segmenters.model_card`): name, label set, input, depth."""
    from evsmap.segmenters.model_card import MODEL_CARDS

    cards = list(MODEL_CARDS.items().values())
    print("model cards:")
    width = max((len(c.name) for c in cards), default=0)
    for c in cards:
        depth = "RGB-D" if c.uses_depth else "RGB"
        print(f"  {c.name:<{width}}  {c.class_set}, {depth}, "
              f"{c.input_size[1]}x{c.input_size[0]}; paper figures: {len(c.published)}, "
              f"known weight files: {len(c.weights)}")
