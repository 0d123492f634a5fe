"""numba's on-disk cache for evsmap's compiled kernels, keyed by the code they were compiled from.

numba's ``cache=True`` keys a compiled function by its own file only: a caller is loaded as it was
compiled even after a jitted function, or a constant, it takes from another module changed (a
cached ``voxel_grid`` gave a centroid 1 ulp off after :mod:`evsmap.mapping.stdsort` changed,
until its cache files were deleted). Here every kernel defined under evsmap's package folder, or
under a plug-in's (the ``evsmap.plugins`` entry points), is located by :class:`KernelLocator`,
whose stamp is the digest of its file *and of every module of evsmap or of its own package that
the file imports, transitively* (:func:`closure_digest`): an edit to any of them recompiles the
kernel, an edit elsewhere recompiles nothing.

Where the files go (numba's order, with evsmap's cache in place of numba's user-wide folder):

* ``$NUMBA_CACHE_DIR`` when the user set it (then ``evsmap cache clear`` leaves it alone);
* else beside the sources, in their ``__pycache__`` folders, as numba does and as Python keeps
  its bytecode (a checkout or a virtual environment the user owns);
* else (a read-only installation) the ``kernels/`` folder of evsmap's cache
  (:func:`evsmap.cache.cache_dir`).

``evsmap cache clear kernels`` removes the last two (:func:`files_beside_sources`).

:func:`install` runs when evsmap's package is imported, before any kernel module: numba chooses a
function's locator when the function is decorated, at its module's import. It imports nothing
heavy (the command line starts without numba): when numba is not imported yet, a one-shot import
hook adds the locator right after numba's own import. A user's ``NUMBA_CACHE_LOCATOR_CLASSES``
replaces numba's list of locators, this one included: the keying is then the user's.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.machinery
import importlib.util
import os
import re
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

from evsmap.cache import cache_dir

KIND = "kernels"
"""The kind (:data:`evsmap.cache.KINDS`) of the folder used where the sources are read-only."""

COMPILED_SUFFIXES = (".nbi", ".nbc")
"""numba's index and data files."""

PLUGIN_GROUP = "evsmap.plugins"


def evsmap_root() -> Path:
    """evsmap's package folder."""
    return Path(__file__).resolve().parents[1]


@functools.cache
def package_roots() -> dict[str, Path]:
    """evsmap's and its plug-ins' top-level packages: ``{name: folder}``, found without importing
    the plug-ins (their kernels are keyed like evsmap's)."""
    from importlib import metadata

    roots = {"evsmap": evsmap_root()}
    for ep in metadata.entry_points(group=PLUGIN_GROUP):
        top = ep.module.split(".")[0]
        if top in roots:
            continue
        spec = importlib.util.find_spec(top)
        if spec is not None and spec.submodule_search_locations:
            roots[top] = Path(next(iter(spec.submodule_search_locations))).resolve()
    return roots


def _package_of(path: Path) -> tuple[str, Path] | None:
    """The evsmap or plug-in package holding ``path`` (the plug-ins are looked up only for a file
    outside evsmap: evsmap never imports them)."""
    if path.is_relative_to(evsmap_root()):
        return "evsmap", evsmap_root()
    for name, folder in package_roots().items():
        if path.is_relative_to(folder):
            return name, folder
    return None


def _module_file(name: str, roots: dict[str, Path]) -> Path | None:
    """The source of module ``name`` (``a.b.c``) when its package is one of ``roots``."""
    top, *rest = name.split(".")
    folder = roots.get(top)
    if folder is None:
        return None
    base = folder.joinpath(*rest)
    for candidate in (base.with_suffix(".py") if rest else None, base / "__init__.py"):
        if candidate is not None and candidate.is_file():
            return candidate
    return None


_IMPORT = re.compile(r"^[ \t]*(?:from[ \t]+(?P<base>\.*[\w.]*)[ \t]+import[ \t]+"
                     r"(?P<names>\([^)]*\)|(?:[^\n\\]|\\\n)*)|import[ \t]+(?P<modules>[^\n]*))",
                     re.MULTILINE)
"""An import statement at the start of a line (in code or prose: a name too many only costs a
needless recompilation). Faster than parsing: the stamps are computed at every start."""


def _names(listed: str) -> list[str]:
    """``a as b, c`` (parenthesised, continued, commented) -> ``["a", "c"]``."""
    listed = re.sub(r"#[^\n]*", "", listed)
    words = (item.strip(" \t\n\\()").split(" as ")[0].strip() for item in listed.split(","))
    return [w for w in words if w and w != "*"]


def _imported_names(path: Path, package: str) -> Iterator[str]:
    """Every module name ``path`` (in ``package``) may import (``from a import b``: ``a`` and
    ``a.b``), relative imports resolved."""
    text = path.read_text(encoding="utf-8", errors="replace")
    for match in _IMPORT.finditer(text):
        if match["modules"] is not None:
            yield from _names(match["modules"].split(";")[0])
            continue
        base = match["base"]
        level = len(base) - len(base.lstrip("."))
        if level:
            parent = package.rsplit(".", level - 1)[0] if level > 1 else package
            base = f"{parent}.{base[level:]}" if base[level:] else parent
        yield base
        yield from (f"{base}.{name}" for name in _names(match["names"]))


@functools.cache
def _direct_imports(path: Path) -> frozenset[Path]:
    """The evsmap modules, and those of ``path``'s own package, that ``path`` imports."""
    found = _package_of(path)
    assert found is not None, path
    name, folder = found
    roots = {"evsmap": evsmap_root(), name: folder}
    parts = [name, *path.relative_to(folder).with_suffix("").parts]
    package = ".".join(parts[:-1])  # a module's package; an __init__'s is itself
    files = (_module_file(n, roots) for n in _imported_names(path, package))
    return frozenset(f.resolve() for f in files if f is not None)


def closure(path: str | os.PathLike[str]) -> list[Path]:
    """``path`` and every module of evsmap or of its own package that it imports, transitively,
    sorted."""
    start = Path(path).resolve()
    seen = {start}
    pending = [start]
    while pending:
        for found in _direct_imports(pending.pop()) - seen:
            seen.add(found)
            pending.append(found)
    return sorted(seen)


@functools.cache
def closure_digest(path: str | os.PathLike[str]) -> str:
    """sha256 of the sources of :func:`closure` (paths relative to their package's parent, and
    bytes): the stamp of the kernels defined in ``path``."""
    h = hashlib.sha256()
    for file in closure(path):
        found = _package_of(file)
        assert found is not None, file
        h.update(file.relative_to(found[1].parent).as_posix().encode() + b"\0")
        h.update(hashlib.sha256(file.read_bytes()).digest())
    return h.hexdigest()


def is_kernel_source(path: str | os.PathLike[str]) -> bool:
    """Whether a function defined in ``path`` is evsmap's or a plug-in's (keyed here)."""
    return os.path.exists(path) and _package_of(Path(path).resolve()) is not None


def _places(py_file: str, subpath: str) -> list[str]:
    """Where the compiled files of ``py_file`` may go, in order (see the module's docstring)."""
    from numba.core import config

    user_dir = str(getattr(config, "CACHE_DIR", "") or "")  # NUMBA_CACHE_DIR
    if user_dir:
        return [os.path.join(user_dir, subpath)]
    return [os.path.join(os.path.dirname(py_file), "__pycache__"), str(cache_dir(KIND) / subpath)]


def _locator_class() -> type[Any]:
    from numba.core.caching import InTreeCacheLocator

    class KernelLocator(InTreeCacheLocator):
        """numba's locator for evsmap's and the plug-ins' kernels: stamped by
        :func:`closure_digest`, placed by :func:`_places`."""

        def __init__(self, py_func: Any, py_file: str, place: str) -> None:
            super().__init__(py_func, py_file)  # type: ignore[no-untyped-call]
            self._place = place

        def get_cache_path(self) -> str:
            return self._place

        def get_source_stamp(self) -> str:
            return closure_digest(self._py_file)

        @classmethod
        def from_function(cls, py_func: Any, py_file: str) -> KernelLocator | None:
            if not is_kernel_source(py_file):
                return None  # numba's own locators
            subpath = cls.get_suitable_cache_subpath(py_file)  # type: ignore[no-untyped-call]
            for place in _places(py_file, subpath):
                locator = cls(py_func, py_file, place)
                try:
                    locator.ensure_cache_path()  # type: ignore[no-untyped-call]
                except OSError:  # not writable: the next place
                    continue
                return locator
            return None

    return KernelLocator


KernelLocator: type[Any] | None = None
"""The locator class, once numba is imported (:func:`configure`)."""


def configure() -> None:
    """Put :class:`KernelLocator` first in numba's locators (once; numba must be imported). On
    a numba whose caching differs, a warning: evsmap still runs, keyed as numba keys."""
    global KernelLocator
    if KernelLocator is not None:
        return
    try:
        from numba.core.caching import CacheImpl

        locator = _locator_class()
        CacheImpl._locator_classes = [locator, *CacheImpl._locator_classes]
    except (ImportError, AttributeError, TypeError) as exc:
        warnings.warn(f"evsmap: compiled kernels keyed by their own file only, as numba does "
                      f"({type(exc).__name__}: {exc}); after updating evsmap, run `evsmap cache "
                      f"clear kernels`", RuntimeWarning, stacklevel=2)
        return
    KernelLocator = locator


class _AfterNumba:
    """A one-shot import hook: lets numba import, then :func:`configure`."""

    def find_spec(self, fullname: str, path: Any = None,
                  target: ModuleType | None = None) -> importlib.machinery.ModuleSpec | None:
        if fullname != "numba":
            return None
        if self in sys.meta_path:
            sys.meta_path.remove(self)
        spec = importlib.util.find_spec("numba")
        if spec is None or spec.loader is None:
            return spec
        exec_module = spec.loader.exec_module

        def exec_then_configure(module: ModuleType) -> None:
            exec_module(module)
            configure()

        setattr(spec.loader, "exec_module", exec_then_configure)  # noqa: B010 - this loader only
        return spec


def install() -> None:
    """Key evsmap's kernels by their code (:func:`configure`), now if numba is imported, else
    right after its import."""
    numba = sys.modules.get("numba")
    if numba is not None and hasattr(numba, "njit"):
        configure()
    elif not any(isinstance(f, _AfterNumba) for f in sys.meta_path):
        sys.meta_path.insert(0, _AfterNumba())


def files_beside_sources() -> list[Path]:
    """numba's files of evsmap's and the plug-ins' kernels in their ``__pycache__`` folders
    (``evsmap cache clear kernels`` removes them with evsmap's ``kernels/`` folder)."""
    return [path for root in package_roots().values() for folder in root.rglob("__pycache__")
            for path in folder.iterdir() if path.suffix in COMPILED_SUFFIXES]
