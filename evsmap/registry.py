"""Plug-in registries: one per kind (segmenter, updater, reader), each typed by the interface
its plug-ins implement (``Registry[Segmenter]``, ``Registry[MapUpdater]``, ``Registry[Sequence]``).

Modelled on torchvision's ``models/_api.py``: a name maps to a factory; registering a taken name
raises, asking for an unknown name raises with the known names and the closest match, and every
factory takes keyword-only arguments so a configuration is always explicit::

    from evsmap.registry import READERS
    seq = READERS.create("synthetic", scene="bedroom", frames=30)

Third-party packages add plug-ins through the ``evsmap.plugins`` entry-point group: each entry
point names a module (or a callable) that registers its plug-ins when imported (or called).
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from importlib import metadata
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from evsmap.errors import DuplicateNameError, EvsmapError, unknown_name

if TYPE_CHECKING:  # the interfaces pull in numpy: naming the plug-ins must not
    from evsmap.data import Sequence
    from evsmap.interfaces import MapUpdater, Segmenter

T = TypeVar("T")

# Modules that register the built-in plug-ins; imported on first use of any registry. The
# comparison systems (`baselines`) come through the `evsmap.plugins` entry point like any
# third-party plug-in.
_BUILTIN_MODULES = (
    "evsmap.readers.tum",
    "evsmap.synth.reader",
    "evsmap.readers.rosbag",
    "evsmap.readers.sevenscenes",
    "evsmap.readers.scannet.reader",
    "evsmap.datasets.nyuv2",
    "evsmap.datasets.sunrgbd",
    "evsmap.datasets.cityscapes",
    "evsmap.datasets.synthrooms",
    "evsmap.segmenters.zoo",
    "evsmap.updaters.registered",
    "evsmap.segmenters.oracle",
)
_loaded = False


@dataclass(frozen=True)
class Entry(Generic[T]):
    """One registered plug-in."""

    name: str
    factory: Callable[..., T]
    description: str
    kind: str
    extras: dict[str, Any] = field(default_factory=dict)

    def parameters(self) -> dict[str, inspect.Parameter]:
        """The factory's keyword-only parameters, by name."""
        return dict(inspect.signature(self.factory).parameters)


class Registry(Generic[T]):
    """Names -> factories for one kind of plug-in, every factory returning a ``T`` (the kind's
    interface).

    Args:
        kind: what the registry holds ("segmenter", "updater", "reader"), used in messages.
    """

    def __init__(self, kind: str) -> None:
        self.kind = kind
        self._entries: dict[str, Entry[T]] = {}

    # -- registration -------------------------------------------------------------------------
    def register(
        self, name: str, *, description: str | None = None, **extras: Any
    ) -> Callable[[Callable[..., T]], Callable[..., T]]:
        """Decorator registering ``factory`` under ``name``.

        Raises:
            DuplicateNameError: ``name`` is already taken.
            TypeError: the factory has a positional parameter.
        """

        def decorator(factory: Callable[..., T]) -> Callable[..., T]:
            self.add(name, factory, description=description, **extras)
            return factory

        return decorator

    def add(
        self, name: str, factory: Callable[..., T], *, description: str | None = None,
        **extras: Any,
    ) -> None:
        """Register ``factory`` under ``name`` (the non-decorator form of :meth:`register`)."""
        if not name or name != name.strip() or name.lower() != name:
            raise ValueError(f"{self.kind} name {name!r} must be non-empty lower case")
        if name in self._entries:
            raise DuplicateNameError(
                f"{self.kind} {name!r} is already registered "
                f"(by {_qualname(self._entries[name].factory)})"
            )
        for pname, param in inspect.signature(factory).parameters.items():
            if param.kind in (param.POSITIONAL_ONLY, param.POSITIONAL_OR_KEYWORD,
                              param.VAR_POSITIONAL):
                raise TypeError(
                    f"{self.kind} factory {_qualname(factory)} must take keyword-only arguments; "
                    f"parameter {pname!r} is positional"
                )
        if description is None:
            doc = inspect.getdoc(factory) or ""
            description = doc.strip().splitlines()[0] if doc.strip() else ""
        self._entries[name] = Entry(name, factory, description, self.kind, dict(extras))

    def unregister(self, name: str) -> None:
        """Remove ``name`` (used by tests and by plug-ins that replace themselves)."""
        self.get(name)
        del self._entries[name]

    # -- lookup -------------------------------------------------------------------------------
    def get(self, name: str) -> Entry[T]:
        """The entry for ``name``.

        Raises:
            UnknownNameError: with the known names and the closest match.
        """
        _ensure_builtins()
        try:
            return self._entries[name]
        except KeyError:
            pass
        raise unknown_name(self.kind, name, self._entries) from None

    def create(self, name: str, **config: Any) -> T:
        """Build the plug-in ``name`` with ``config``; unknown options are named in the error."""
        entry = self.get(name)
        params = entry.parameters()
        takes_any = any(p.kind is p.VAR_KEYWORD for p in params.values())
        if not takes_any:
            unknown = sorted(set(config) - set(params))
            if unknown:
                accepted = ", ".join(sorted(params)) or "none"
                raise EvsmapError(
                    f"{self.kind} {name!r} has no option {', '.join(map(repr, unknown))} "
                    f"(accepted: {accepted})"
                )
        _check_option_types(self.kind, name, entry.factory, config)
        return entry.factory(**config)

    def names(self) -> list[str]:
        _ensure_builtins()
        return sorted(self._entries)

    def entries(self) -> list[Entry[T]]:
        _ensure_builtins()
        return [self._entries[n] for n in sorted(self._entries)]

    def __contains__(self, name: object) -> bool:
        _ensure_builtins()
        return name in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self.names())


_TYPE_WORDS = {float: "a number", int: "an integer", bool: "true or false", str: "a text"}


def _accepts(hint: Any, value: Any) -> bool | None:
    """Whether ``value`` fits the annotation ``hint`` (None: the hint is not one we check)."""
    import types
    import typing

    if hint in (float, int):
        ok = isinstance(value, (int, float)) if hint is float else isinstance(value, int)
        return ok and not isinstance(value, bool)
    if hint in (bool, str):
        return isinstance(value, hint)
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        if value is None:
            return type(None) in typing.get_args(hint)
        verdicts = [_accepts(h, value) for h in typing.get_args(hint) if h is not type(None)]
        if any(v is None for v in verdicts):
            return None
        return any(verdicts)
    return None


def _check_option_types(kind: str, name: str, factory: Callable[..., Any],
                        config: dict[str, Any]) -> None:
    """One clear error for an option whose value has the wrong type for the factory's
    annotation (``-o psi=abc`` where a number is expected)."""
    import typing

    hints = _option_hints(factory)
    for key, value in config.items():
        hint = hints.get(key)
        if hint is None or _accepts(hint, value) is not False:
            continue
        words = [_TYPE_WORDS[h] for h in (typing.get_args(hint) or (hint,)) if h in _TYPE_WORDS]
        want = " or ".join(words) or str(hint)
        raise EvsmapError(f"{kind} {name!r}: option {key} must be {want}, got {value!r}")


def _option_hints(factory: Callable[..., Any]) -> dict[str, Any]:
    """The factory's parameter annotations, resolved one by one: an annotation that does not
    resolve (a name imported only for type checkers, as the return types of factories that
    import their class when called) is left unchecked, the others still are."""
    import typing

    annotations = dict(getattr(factory, "__annotations__", {}))
    annotations.pop("return", None)
    namespace = getattr(factory, "__globals__", {})
    hints = {}
    for name, annotation in annotations.items():
        try:
            hints[name] = (typing.get_type_hints(_Annotated(annotation), namespace)["x"])
        except Exception:  # noqa: BLE001 - annotations we cannot resolve are not checked
            continue
    return hints


class _Annotated:
    """An object whose only annotation is ``annotation`` (so ``typing.get_type_hints``
    resolves one annotation at a time)."""

    def __init__(self, annotation: Any) -> None:
        self.__annotations__ = {"x": annotation}


def _qualname(obj: object) -> str:
    return f"{getattr(obj, '__module__', '?')}.{getattr(obj, '__qualname__', repr(obj))}"


SEGMENTERS: Registry[Segmenter] = Registry("segmenter")
UPDATERS: Registry[MapUpdater] = Registry("updater")
READERS: Registry[Sequence] = Registry("reader")


def list_segmenters() -> list[str]:
    return SEGMENTERS.names()


def list_updaters() -> list[str]:
    return UPDATERS.names()


def list_readers() -> list[str]:
    return READERS.names()


def get_segmenter(name: str, **config: Any) -> Segmenter:
    return SEGMENTERS.create(name, **config)


def get_updater(name: str, **config: Any) -> MapUpdater:
    return UPDATERS.create(name, **config)


def get_reader(name: str, **config: Any) -> Sequence:
    return READERS.create(name, **config)


def _ensure_builtins() -> None:
    """Import the built-in plug-in modules and the ``evsmap.plugins`` entry points once."""
    global _loaded
    if _loaded:
        return
    _loaded = True
    for module in _BUILTIN_MODULES:
        importlib.import_module(module)
    for ep in metadata.entry_points(group="evsmap.plugins"):
        try:
            target = ep.load()
        except Exception as exc:  # a broken third-party plug-in must not hide the built-ins
            raise EvsmapError(
                f"plug-in entry point {ep.name!r} ({ep.value}) failed to load: {exc}") from exc
        if callable(target) and not inspect.ismodule(target):
            target()
