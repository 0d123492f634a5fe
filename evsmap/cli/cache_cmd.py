"""``evsmap cache info|clear``: the cache shared across runs (:mod:`evsmap.cache`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from evsmap.cache import KINDS, cache_dir, clear, folder_size, info
from evsmap.errors import EvsmapError


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("cache", help="the cache shared across runs (ONNX exports, "
                                     "segmentations, rendered sequences, compiled kernels)",
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


def _check_root() -> None:
    """A cache root that is not a folder: one line naming it and the variable that sets it."""
    from evsmap.cache import CACHE_ENV, cache_root

    root = cache_root()
    if root.exists() and not root.is_dir():
        raise EvsmapError(f"{root}: is a file, not a cache folder (set ${CACHE_ENV} to a folder, "
                          "or unset it for ~/.cache/evsmap)")


def _kernels_beside_sources() -> list[Path]:
    """numba's files of evsmap's and the plug-ins' kernels in their ``__pycache__`` folders:
    part of the ``kernels`` kind (:mod:`evsmap.mapping.jit_cache`)."""
    from evsmap.mapping.jit_cache import files_beside_sources

    return files_beside_sources()


def _with_kernels_beside_sources(data: dict) -> dict:
    """:func:`evsmap.cache.info` with the kernels' files beside the sources counted in."""
    paths = _kernels_beside_sources()
    size = sum(_file_size(p) for p in paths)
    kernels = data["kinds"]["kernels"]
    kernels["beside_sources"] = {"files": len(paths), "bytes": size}
    kernels["files"] += len(paths)
    kernels["bytes"] += size
    data["bytes"] += size
    return data


def _file_size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:  # removed meanwhile
        return 0


def _clear_kernels_beside_sources() -> tuple[int, list[Path]]:
    """Remove the kernels' files beside the sources: (bytes freed, paths left)."""
    freed, left = 0, []
    for path in _kernels_beside_sources():
        size = _file_size(path)
        try:
            path.unlink()
            freed += size
        except FileNotFoundError:
            pass
        except OSError:
            left.append(path)
    return freed, left


def run_info(args: argparse.Namespace) -> int:
    _check_root()
    data = _with_kernels_beside_sources(info())
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
    if args.all and args.kinds:
        raise EvsmapError(f"--all clears every kind: leave out {' '.join(args.kinds)}, or "
                          "leave out --all to clear only those")
    if not args.all and not args.kinds:
        raise EvsmapError("name the kinds to clear (" + ", ".join(KINDS) + ") or pass --all")
    _check_root()
    kinds = list(KINDS) if args.all else list(dict.fromkeys(args.kinds))
    freed = clear(kinds)
    if "kernels" in kinds:
        beside, stuck = _clear_kernels_beside_sources()
        freed += beside
        if stuck:
            raise EvsmapError(f"{stuck[0].parent}: {len(stuck)} compiled kernel files could not "
                              f"be removed (check their permissions); {freed / 1e6:.1f} MB freed "
                              f"before that")
    left = {k: folder_size(cache_dir(k)) for k in kinds}
    left = {k: v for k, v in left.items() if v[0]}
    if left:  # files that could not be removed (permissions, a busy file system)
        kind, (files, size) = next(iter(left.items()))
        raise EvsmapError(f"{cache_dir(kind)}: {files} files ({size / 1e6:.1f} MB) could not be "
                          f"removed (check their permissions); {freed / 1e6:.1f} MB freed "
                          f"before that")
    print(f"cleared {', '.join(kinds)}: {freed / 1e6:.1f} MB freed")
    return 0
