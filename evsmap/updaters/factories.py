"""Registered updater factories that state only what differs from the octree base.

As timm's model variants, a registered factory is a constructor with a few options added or
their defaults changed: :func:`octree_factory` makes one from the function that builds the
updater and those options. Its signature is every option of
:class:`~evsmap.updaters.tree_map.OctreeMap`'s constructor (:data:`OCTREE_OPTIONS`, from
:class:`~evsmap.mapping.options.OctreeOptions`) and the ones stated, so each
is reachable with ``-o`` / a systems file, checked by name and type
(:meth:`evsmap.registry.Registry.create`) and named in the error that lists them.

The module needs neither numba nor the updaters: the function given imports its class when
called, so naming and checking the updaters loads no kernels.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable
from typing import Any, TypeVar

from evsmap.mapping.options import OCTREE_DEFAULTS

T = TypeVar("T")

OCTREE_OPTIONS: dict[str, Any] = OCTREE_DEFAULTS.as_options()
"""The options of :class:`~evsmap.updaters.tree_map.OctreeMap`'s constructor, with its defaults
(:data:`~evsmap.mapping.options.OCTREE_DEFAULTS`, which the constructor reads too)."""

_TYPES = {bool: "bool", int: "int", float: "float", str: "str"}


def _annotation(name: str, default: Any) -> str:
    """``default``'s type as an annotation; ``None`` (chosen by the updater) is allowed beside
    the base option's type."""
    if default is None:
        return f"{_TYPES[type(OCTREE_OPTIONS[name])]} | None"
    return _TYPES[type(default)]


def octree_factory(build: Callable[..., T], /, **options: Any) -> Callable[..., T]:
    """A factory taking :data:`OCTREE_OPTIONS` updated with ``options`` (new options or other
    defaults; ``None`` leaves an option's default to the updater ``build`` makes): calling it
    calls ``build`` with every option, the defaults filled in.

    Args:
        build: makes the updater from keyword options (importing its class when called).
        options: name -> default; the annotation is the default's type.
    """
    defaults = {**OCTREE_OPTIONS, **options}
    params = [inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=default,
                                annotation=_annotation(name, default))
              for name, default in defaults.items()]
    signature = inspect.Signature(params)

    def factory(**given: Any) -> T:
        bound = signature.bind(**given)
        bound.apply_defaults()
        return build(**bound.arguments)

    setattr(factory, "__signature__", signature)  # noqa: B010 - no such attribute for mypy
    factory.__annotations__ = {p.name: p.annotation for p in params}
    named = build.func if isinstance(build, functools.partial) else build
    for attr in ("__module__", "__name__", "__qualname__", "__doc__"):
        setattr(factory, attr, getattr(named, attr))
    return factory


def given(options: dict[str, Any], *names: str) -> dict[str, Any]:
    """``options`` without ``names`` and without options left ``None`` (the updater's own
    default applies)."""
    return {k: v for k, v in options.items() if k not in names and v is not None}
