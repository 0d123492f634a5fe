"""Plug-in registries: one per kind (segmenter, updater, reader), each typed by the interface
its plug-ins implement (``Registry[Segmenter]``, ``Registry[MapUpdater]``, ``Registry[Sequence]``).

Modelled on torchvision's ``models/_api.py``: a name maps to a factory; registering a taken name
raises, asking for an unknown name raises with the known names and the closest match, and every
factory takes keyword-only arguments so a configuration is always explicit::

    from evsmap.registry import READERS
    seq = READERS.create("synthetic", scene="bedroom", frames=30)

What a plug-in takes is declared once, where it is registered (timm's style): ``takes=``
(:class:`Takes`: a network's weights, backend and input size; a reader's path, split, limit,
camera, resolution; an updater's resolution) and the factory's options (:class:`Option`, read
from its signature at registration). Callers read :attr:`Entry.takes` and
:attr:`Entry.options`; nothing outside this module looks at a factory's parameters. A plug-in
registered without ``takes=`` (a third-party one written before it existed) gets it derived
from its signature then, once; a declared ``takes`` is checked against the signature, so the
two cannot drift apart.

Third-party packages add plug-ins through the ``evsmap.plugins`` entry-point group: each entry
point names a module (or a callable) that registers its plug-ins when imported (or called).
"""

from __future__ import annotations

import importlib
import inspect
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field, fields
from importlib import metadata
from types import MappingProxyType
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
class Takes:
    """What a plug-in's factory takes besides its own settings, declared where it is registered;
    each field is named after the keyword option it stands for, and True means the factory takes
    that option (the registry checks it against the factory's signature).

    Attributes:
        weights: segmenter: a trained weights file (a network; ``--weights``).
        backend: segmenter: the inference backend (``torch``, ``onnxruntime``): it can run on a
            device and at a precision (``--device``, ``--precision``).
        input_size: segmenter: the network's input size (H, W) (``--size``).
        path: reader: the file or folder it reads; without it the sequence is built from options
            alone (``synthetic``) and named by the reader's name.
        split: reader: a dataset split (``train``, ``val``, ``test``).
        limit: reader: the first N frames only.
        camera: reader: the camera's intrinsics by name (TUM's ``fr1``, ``fr2``, ...).
        resolution: updater: the leaf size in metres; reader: the frames' size ``WxH``.
    """

    weights: bool = False
    backend: bool = False
    input_size: bool = False
    path: bool = False
    split: bool = False
    limit: bool = False
    camera: bool = False
    resolution: bool = False


NETWORK = Takes(weights=True, backend=True, input_size=True)
"""What every network segmenter takes: trained weights, a backend and an input size."""

OCTREE = Takes(resolution=True)
"""What every octree map updater takes: the leaf size."""


class _Required:
    """The default of an option that has none (the caller must give it)."""

    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED: Any = _Required()


@dataclass(frozen=True)
class Option:
    """One keyword option of a plug-in's factory.

    Attributes:
        name: the option's name (``-o NAME=VALUE``, a systems file's key).
        default: its default, or :data:`REQUIRED`.
    """

    name: str
    default: Any = REQUIRED

    @property
    def required(self) -> bool:
        return self.default is REQUIRED


@dataclass(frozen=True)
class Entry(Generic[T]):
    """One registered plug-in.

    Attributes:
        takes: what it takes (:class:`Takes`), declared at registration or derived from the
            factory's signature there.
        options: the factory's keyword options by name, in its order.
        any_option: the factory takes any option (``**options``) besides :attr:`options`.
        extras: the other facts given at registration (a reader's ``detect``, a network's
            ``paper_size``, ...).
    """

    name: str
    factory: Callable[..., T]
    description: str
    kind: str
    takes: Takes = Takes()
    options: Mapping[str, Option] = field(default_factory=lambda: MappingProxyType({}))
    any_option: bool = False
    extras: dict[str, Any] = field(default_factory=dict)

    def defaults(self) -> dict[str, Any]:
        """The options that have a default, with it."""
        return {k: o.default for k, o in self.options.items() if not o.required}


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
        self, name: str, *, description: str | None = None, takes: Takes | None = None,
        **extras: Any,
    ) -> Callable[[Callable[..., T]], Callable[..., T]]:
        """Decorator registering ``factory`` under ``name``.

        Raises:
            DuplicateNameError: ``name`` is already taken.
            TypeError: the factory has a positional parameter, or ``takes`` does not match it.
        """

        def decorator(factory: Callable[..., T]) -> Callable[..., T]:
            self.add(name, factory, description=description, takes=takes, **extras)
            return factory

        return decorator

    def add(
        self, name: str, factory: Callable[..., T], *, description: str | None = None,
        takes: Takes | None = None, **extras: Any,
    ) -> None:
        """Register ``factory`` under ``name`` (the non-decorator form of :meth:`register`).

        ``takes`` declares what the factory takes (:class:`Takes`); left out, it is derived here
        from the factory's signature (each field True where the factory has that option)."""
        if not name or name != name.strip() or name.lower() != name:
            raise ValueError(f"{self.kind} name {name!r} must be non-empty lower case")
        if name in self._entries:
            raise DuplicateNameError(
                f"{self.kind} {name!r} is already registered "
                f"(by {_qualname(self._entries[name].factory)})"
            )
        options, any_option = _factory_options(self.kind, factory)
        derived = Takes(**{f.name: f.name in options for f in fields(Takes)})
        if takes is None:
            takes = derived
        else:
            _check_takes(f"{self.kind} {name!r}", takes, derived, any_option=any_option)
        if description is None:
            doc = inspect.getdoc(factory) or ""
            description = doc.strip().splitlines()[0] if doc.strip() else ""
        self._entries[name] = Entry(name, factory, description, self.kind, takes,
                                    MappingProxyType(options), any_option, dict(extras))

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
        if not entry.any_option:
            unknown = sorted(set(config) - set(entry.options))
            if unknown:
                accepted = ", ".join(sorted(entry.options)) or "none"
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


def _factory_options(kind: str, factory: Callable[..., Any]) -> tuple[dict[str, Option], bool]:
    """``(options, any_option)``: the factory's keyword-only options and whether it takes any
    other (``**options``); read once, when the factory is registered.

    Raises:
        TypeError: the factory has a positional parameter.
    """
    options: dict[str, Option] = {}
    any_option = False
    for pname, param in inspect.signature(factory).parameters.items():
        if param.kind in (param.POSITIONAL_ONLY, param.POSITIONAL_OR_KEYWORD,
                          param.VAR_POSITIONAL):
            raise TypeError(
                f"{kind} factory {_qualname(factory)} must take keyword-only arguments; "
                f"parameter {pname!r} is positional"
            )
        if param.kind is param.VAR_KEYWORD:
            any_option = True
            continue
        default = REQUIRED if param.default is param.empty else param.default
        options[pname] = Option(pname, default)
    return options, any_option


def _check_takes(what: str, declared: Takes, derived: Takes, *, any_option: bool) -> None:
    """Refuse a declared :class:`Takes` that differs from what the factory's options say (a
    factory taking any option, ``**options``, may declare more than it names).

    Raises:
        TypeError: naming the first field that differs.
    """
    for f in fields(Takes):
        said, has = getattr(declared, f.name), getattr(derived, f.name)
        if said and not has and not any_option:
            raise TypeError(f"{what} declares takes.{f.name} but its factory has no option "
                            f"{f.name!r}")
        if has and not said:
            raise TypeError(f"{what}: its factory takes {f.name!r}; declare it "
                            f"(takes=Takes({f.name}=True, ...))")


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
