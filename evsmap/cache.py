"""evsmap's cache shared across runs: ``$EVSMAP_CACHE_DIR``, else ``~/.cache/evsmap``.

What is expensive to make and depends only on its inputs lives here, content-addressed, so a
second ``reproduce`` reuses the first one's work and a run folder keeps only its records,
tables, plots and small artifacts:

* ``onnx/`` - ONNX exports, keyed by the network, its options and a digest of its weights
  (:mod:`evsmap.models.onnx_export`; the speed cells' size-free exports:
  :mod:`evsmap.models.speed_export`);
* ``complexity/`` - fvcore's counts of a network at an input size, keyed by the network's
  structure and code (not its weights, which do not change them) and fvcore's version
  (:func:`evsmap.measure.complexity.cached_complexity`);
* ``segmentation/`` - a sequence's per-frame top-3 observations, keyed by the segmenter, its
  weights' tensors, the sequence and its frames (timings are never shared: they stay in the
  run folder);
* ``sequences/`` - the built-in synthetic scene rendered once, keyed by its options and a digest
  of the renderer's source code;
* ``gate/`` - what ``evsmap gate --against REF`` keeps per reference commit (its ONNX exports
  and other caches, ``gate/reference/<commit>``) and the virtual environments of references
  whose lock differs from this tree's (``gate/envs/<lock digest>``);
* ``explore/`` - the paired baseline maps of ``evsmap explore``'s trials (sizes and 3D quality,
  exact), keyed by the baseline, the shared settings, the observations and the code's digests
  (:mod:`evsmap.explore.bench`);
* ``kernels/`` - numba's compiled kernels where evsmap's sources are read-only (otherwise they
  sit beside the sources, in ``__pycache__``), keyed by their code and the code they import
  (:mod:`evsmap.mapping.jit_cache`); ``evsmap cache clear kernels`` removes both;
* ``calibration.json`` - the best calibration each machine has shown
  (:mod:`evsmap.measure.contention`).

``evsmap cache info`` lists it, ``evsmap cache clear`` empties it.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

CACHE_ENV = "EVSMAP_CACHE_DIR"
KINDS = ("onnx", "complexity", "segmentation", "sequences", "gate", "explore", "kernels")


def cache_root() -> Path:
    """``$EVSMAP_CACHE_DIR`` when set, else ``~/.cache/evsmap``."""
    root = os.environ.get(CACHE_ENV)
    return Path(root).expanduser() if root else Path.home() / ".cache" / "evsmap"


def cache_dir(kind: str) -> Path:
    """The folder of one kind of cached thing (:data:`KINDS`)."""
    if kind not in KINDS:
        raise ValueError(f"unknown cache kind {kind!r} (known: {', '.join(KINDS)})")
    return cache_root() / kind


def source_digest(package: str) -> str:
    """12 hex digits of the sha256 of a package's ``.py`` sources (sorted by path): changes
    whenever its code does, so renders of an older version are never reused."""
    import importlib

    module = importlib.import_module(package)
    assert module.__file__ is not None, f"{package} is not a regular package"
    folder = Path(module.__file__).parent
    h = hashlib.sha256()
    for path in sorted(folder.rglob("*.py")):
        h.update(path.relative_to(folder).as_posix().encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:12]


def folder_size(path: str | os.PathLike[str]) -> tuple[int, int]:
    """(files, bytes) under ``path`` (0, 0 when it does not exist): regular files and what
    file links point to; linked folders are not entered (as :func:`os.walk` does). One
    ``scandir`` per folder and one ``stat`` per file (a cache holding a reference's virtual
    environment is 56 000 files: 0.3 s, not the 2 s of a walk building a path per file)."""
    files = size = 0
    pending = [os.fspath(path)]
    while pending:
        try:
            with os.scandir(pending.pop()) as entries:
                for entry in entries:
                    try:
                        if entry.is_dir():
                            if not entry.is_symlink():
                                pending.append(entry.path)
                            continue
                        size += entry.stat().st_size
                        files += 1
                    except OSError:  # removed meanwhile, or a dangling link
                        pass
        except OSError:  # missing or unreadable
            pass
    return files, size


def info() -> dict:
    """The cache's root and, per kind, its entries and bytes."""
    root = cache_root()
    kinds = {}
    for kind in KINDS:
        folder = root / kind
        entries = len(list(folder.iterdir())) if folder.is_dir() else 0
        files, size = folder_size(folder)
        kinds[kind] = {"path": str(folder), "entries": entries, "files": files, "bytes": size}
    return {"root": str(root), "kinds": kinds,
            "bytes": sum(k["bytes"] for k in kinds.values())}


def clear(kinds: list[str]) -> int:
    """Remove the given kinds of cached things; returns the bytes freed."""
    freed = 0
    for kind in kinds:
        folder = cache_dir(kind)
        freed += folder_size(folder)[1]
        shutil.rmtree(folder, ignore_errors=True)
    return freed
