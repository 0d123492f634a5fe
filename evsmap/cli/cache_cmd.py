"""``evsmap cache info|clear``: the cache shared across runs (:mod:`evsmap.cache`)."""

from __future__ import annotations

import argparse
import json

from evsmap.cache import KINDS, clear, info
from evsmap.errors import EvsmapError


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("cache", help="the cache shared across runs (ONNX exports, "
                                     "segmentations, rendered sequences)",
                       description="The cache shared across runs: $EVSMAP_CACHE_DIR, else "
                                   "~/.cache/evsmap.")
    actions = p.add_subparsers(dest="action", required=True, metavar="info|clear")
    i = actions.add_parser("info", help="what the cache holds, per kind")
    i.add_argument("--json", action="store_true", help="print JSON")
    i.set_defaults(run=run_info)
    c = actions.add_parser("clear", help="empty the cache (some kinds, or all)")
    c.add_argument("kinds", nargs="*", metavar="KIND",
                   help=f"kinds to remove ({', '.join(KINDS)}); none: pass --all")
    c.add_argument("--all", action="store_true", help="remove every kind")
    c.set_defaults(run=run_clear)


def run_info(args: argparse.Namespace) -> int:
    data = info()
    if args.json:
        print(json.dumps(data, indent=2))
        return 0
    print(f"cache        {data['root']}  ({data['bytes'] / 1e6:.1f} MB)")
    for kind, k in data["kinds"].items():
        print(f"{kind:<12} {k['entries']:>5} entries, {k['files']:>6} files, "
              f"{k['bytes'] / 1e6:9.1f} MB")
    return 0


def run_clear(args: argparse.Namespace) -> int:
    unknown = [k for k in args.kinds if k not in KINDS]
    if unknown:
        raise EvsmapError(f"unknown cache kind {unknown[0]!r} (known: {', '.join(KINDS)})")
    if args.all == bool(args.kinds):
        raise EvsmapError("name the kinds to clear (" + ", ".join(KINDS) + ") or pass --all")
    kinds = list(KINDS) if args.all else args.kinds
    freed = clear(kinds)
    print(f"cleared {', '.join(kinds)}: {freed / 1e6:.1f} MB freed")
    return 0
