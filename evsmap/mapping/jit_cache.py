"""numba's on-disk cache for evsmap's compiled kernels, keyed by the code they were compiled from.

numba's ``cache=True`` keys a compiled function by its own file only: a caller is loaded as it was
compiled even after a jitted function, or a constant, it takes from another module changed (a
cached ``voxel_grid`` gave a centroid 1 ulp off after :mod:`evsmap.mapping.stdsort` changed,
until its cache files were deleted). Here every kernel defined under evsmap's package folder, or
under a plug-in's (the ``evsmap.plugins`` entry points), is located by :class:`KernelLocator`,
whose stamp is the digest of its file *and of every evsmap or plug-in module that file imports,
transitively* (:func:`closure_digest`): an edit to any of them recompiles the kernel.

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


@functools.cache
def package_roots() -> dict[str, Path]:
    """evsmap's and its plug-ins' top-level packages: ``{name: folder}``, found without importing
    the plug-ins (their kernels are keyed like evsmap's)."""
    from importlib import metadata

    roots = {"evsmap": Path(__file__).resolve().parents[1]}
    for ep in metadata.entry_points(group=PLUGIN_GROUP):
        top = ep.module.split(".")[0]
        if top in roots:
            continue
        spec = importlib.util.find_spec(top)
        if spec is not None and spec.submodule_search_locations:
            roots[top] = Path(next(iter(spec.submodule_search_locations))).resolve()
    return roots


def _root_of(path: Path) -> tuple[str, Path] | None:
    for name, folder in package_roots().items():
        if path.is_relative_to(folder):
            return name, folder
    return None


def _module_file(name: str) -> Path | None:
    """The source of the evsmap or plug-in module ``name`` (``a.b.c``), None when it is not one."""
    top, *rest = name.split(".")
    folder = package_roots().get(top)
    if folder is None:
        return None
    base = folder.joinpath(*rest)
    for candidate in (base.with_suffix(".py") if rest else None, base / "__init__.py"):
        if candidate is not None and candidate.is_file():
            return candidate
    return None


def _module_name(path: Path) -> str:
    found = _root_of(path)
    assert found is not None, path
    name, folder = found
    parts = [name, *path.relative_to(folder).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imported_names(path: Path) -> Iterator[str]:
    """Every module name ``path`` may import (anywhere in it; ``from a import b``: ``a`` and
    ``a.b``), relative imports resolved."""
    import ast

    package = _module_name(path)
    if path.name != "__init__.py":
        package = package.rpartition(".")[0]
    try:
        tree = ast.parse(path.read_bytes(), str(path))
    except (SyntaxError, ValueError):  # its own import fails; its bytes still count
        return
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{parent}.{base}" if base else parent
            yield base
            yield from (f"{base}.{alias.name}" for alias in node.names)


@functools.cache
def _direct_imports(path: Path) -> frozenset[Path]:
    files = (_module_file(name) for name in _imported_names(path))
    return frozenset(f.resolve() for f in files if f is not None)


def closure(path: str | os.PathLike[str]) -> list[Path]:
    """``path`` and every evsmap or plug-in module it imports, transitively, sorted."""
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
        found = _root_of(file)
        assert found is not None, file
        h.update(file.relative_to(found[1].parent).as_posix().encode() + b"\0")
        h.update(hashlib.sha256(file.read_bytes()).digest())
    return h.hexdigest()


def is_kernel_source(path: str | os.PathLike[str]) -> bool:
    """Whether a function defined in ``path`` is evsmap's or a plug-in's (keyed here)."""
    return os.path.exists(path) and _root_of(Path(path).resolve()) is not None


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
    """Put :class:`KernelLocator` first in numba's locators (once; numba must be imported)."""
    global KernelLocator
    if KernelLocator is not None:
        return
    from numba.core.caching import CacheImpl

    KernelLocator = _locator_class()
    CacheImpl._locator_classes = [KernelLocator, *CacheImpl._locator_classes]


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
            try:
                configure()
            except Exception as exc:  # a numba whose caching differs: evsmap still runs
                warnings.warn(f"evsmap: compiled kernels keyed by their own file only, as numba "
                              f"does ({type(exc).__name__}: {exc}); after updating evsmap, run "
                              f"`evsmap cache clear kernels`", RuntimeWarning, stacklevel=2)

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
