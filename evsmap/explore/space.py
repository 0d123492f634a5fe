"""The search space of ``evsmap explore``, as data: a TOML file naming the map updater explored,
its parameters (each a range or a list of choices, with the paper's default, which is the
study's first trial), the baseline it is paired with, the reference it is timed against, the
sampler and the objectives the sampler steers by.

Parameters are of two kinds (``target``):

* ``shared``: the front end's settings (``resolution``, ``max_range``, ``raycast_range``), given
  to the explored updater, the paired baseline and the reference alike wherever their factory
  takes the option, so every map of a trial is made at the same settings;
* ``updater``: the explored updater's own options (``psi``, ``phi``, ``theta``, the clamps...),
  any option its registered factory takes (``evsmap list``, :mod:`evsmap.updaters.factories`).

``evsmap/explore/spaces/<updater>.toml`` is the shipped space of an updater; ``--space FILE``
gives another. :func:`load_space` checks the file whole before a trial runs: an unknown option,
a range the updater refuses (each bound and the default are tried on the updater's constructor),
an empty space; one line names the file and the parameter.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Literal

from evsmap.errors import EvsmapError

SHIPPED = "evsmap.explore.spaces"
"""The package holding the shipped spaces, one per updater (``<updater>.toml``)."""

TARGETS = ("shared", "updater")
SHARED_OPTIONS = ("resolution", "max_range", "raycast_range")
"""The front end's settings a ``shared`` parameter may set."""

SAMPLERS = ("tpe", "nsga2")
DIRECTIONS = ("minimize", "maximize")

OBJECTIVES: dict[str, tuple[str, str]] = {
    "map_size": ("minimize", "the map's size in Table IV's reading (bytes)"),
    "scene_miou": ("maximize", "3D mIoU over the observed scene (a dropped voxel is a miss)"),
    "map_miou": ("maximize", "3D mIoU of the leaves the map kept, against ground truth"),
    "semantic_accuracy": ("maximize", "3D semantic accuracy of the matched leaves"),
    "rate_ratio": ("maximize", "update_hz over OctoMap C++'s, timed in the same process"),
    "size_ratio": ("maximize", "the paired baseline's map size over this map's"),
}
"""What a trial measures that the sampler may steer by, with its natural direction."""


class SpaceError(EvsmapError):
    """A search space that cannot be explored (the message names the file and the entry)."""


@dataclass(frozen=True)
class Parameter:
    """One dimension of the space.

    Attributes:
        name: the option's name (an updater option, or one of :data:`SHARED_OPTIONS`).
        target: ``shared`` or ``updater``.
        default: the paper's value (the first trial's).
        low, high, log, step: a numeric range (``step``: a grid from ``low``).
        choices: the values of a categorical parameter (instead of a range).
        source: where the default comes from.
    """

    name: str
    target: Literal["shared", "updater"]
    default: Any
    low: float | None = None
    high: float | None = None
    log: bool = False
    step: float | None = None
    integer: bool = False
    choices: tuple[Any, ...] = ()
    source: str = ""

    def values_to_try(self) -> list[Any]:
        """The values the updater's constructor is tried with: the bounds (or every choice) and
        the default."""
        values = list(self.choices) if self.choices else [self.low, self.high]
        return values + [self.default]

    def describe(self) -> str:
        if self.choices:
            return "{" + ", ".join(f"{c:g}" if isinstance(c, float) else str(c)
                                   for c in self.choices) + "}"
        text = f"[{self.low:g}, {self.high:g}]"
        if self.log:
            text += " log"
        if self.step is not None:
            text += f" step {self.step:g}"
        return text


@dataclass(frozen=True)
class Objective:
    name: str
    direction: Literal["minimize", "maximize"]


@dataclass(frozen=True)
class Space:
    """A search space (:func:`load_space`).

    Attributes:
        path: the file it was read from.
        updater: the registered updater explored.
        baseline: the Table IV row whose updater is mapped beside each trial at the same shared
            settings (``""``: none).
        reference: the updater the update rate is a ratio to (OctoMap C++).
        parameters: the dimensions, in the file's order.
        objectives: what the sampler steers by (the rest is measured and recorded all the same).
        sampler: ``tpe`` or ``nsga2``; ``seed``, ``population`` (NSGA-II's), ``startup_trials``
            (TPE's random start).
        text: the file's text (stored with the study: a resumed study checks it is the same).
    """

    path: str
    updater: str
    baseline: str
    reference: str
    parameters: tuple[Parameter, ...]
    objectives: tuple[Objective, ...]
    sampler: str = "tpe"
    seed: int = 0
    population: int = 10
    startup_trials: int = 10
    text: str = ""
    fixed: dict[str, Any] = field(default_factory=dict)
    """Options held at a value for every trial (``[fixed]``), shared or the updater's."""

    def defaults(self) -> dict[str, Any]:
        """The paper's point: every parameter at its default."""
        return {p.name: p.default for p in self.parameters}

    def split(self, params: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
        """A trial's ``params`` (and the fixed options) as (shared settings, updater options)."""
        shared = {k: v for k, v in self.fixed.items() if k in SHARED_OPTIONS}
        own = {k: v for k, v in self.fixed.items() if k not in SHARED_OPTIONS}
        for p in self.parameters:
            (shared if p.target == "shared" else own)[p.name] = params[p.name]
        return shared, own


def shipped_space(updater: str) -> Path | None:
    """The shipped space of ``updater``, if there is one."""
    path = Path(str(resources.files(SHIPPED).joinpath(f"{updater}.toml")))
    return path if path.is_file() else None


def shipped_updaters() -> list[str]:
    folder = Path(str(resources.files(SHIPPED)))
    return sorted(p.stem for p in folder.glob("*.toml"))


def load_space(path: str | Path) -> Space:
    """The space in ``path``, checked whole against the registry (:class:`SpaceError`)."""
    where = Path(path)
    try:
        text = where.read_text(encoding="utf-8")
    except OSError as exc:
        raise SpaceError(f"--space {where}: cannot read ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise SpaceError(f"--space {where}: not UTF-8 text") from None
    return space_from_text(text, where)


def space_from_text(text: str, path: str | Path) -> Space:
    """The space a file at ``path`` holding ``text`` gives (a study's stored space is read back
    this way), checked whole against the registry (:class:`SpaceError`)."""
    where = Path(path)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpaceError(f"--space {where}: not valid TOML ({exc})") from None
    space = _parse(data, where, text)
    check_space(space)
    return space


def _need(table: dict[str, Any], key: str, kind: type | tuple[type, ...], where: str) -> Any:
    if key not in table:
        raise SpaceError(f"{where}: {key} is missing")
    value = table[key]
    if isinstance(value, bool) and kind is not bool or not isinstance(value, kind):
        raise SpaceError(f"{where}: {key} has the wrong type ({value!r})")
    return value


def _parse(data: dict[str, Any], where: Path, text: str) -> Space:
    known = {"updater", "baseline", "reference", "sampler", "objectives", "parameters",
             "fixed", "description"}
    for key in data:
        if key not in known:
            raise SpaceError(f"--space {where}: unknown entry {key!r} (known: "
                             f"{', '.join(sorted(known))})")
    updater = _need(data, "updater", str, f"--space {where}")
    sampler = dict(data.get("sampler", {}))
    name = sampler.pop("name", "tpe")
    if name not in SAMPLERS:
        raise SpaceError(f"--space {where}: [sampler] name must be one of "
                         f"{', '.join(SAMPLERS)}, got {name!r}")
    numbers = {}
    for key, default, low in (("seed", 0, 0), ("population", 10, 2), ("startup_trials", 10, 0)):
        value = sampler.pop(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise SpaceError(f"--space {where}: [sampler] {key} must be an integer >= {low}, "
                             f"got {value!r}")
        numbers[key] = value
    if sampler:
        raise SpaceError(f"--space {where}: [sampler] has unknown entries "
                         f"{', '.join(sorted(sampler))}")
    objectives = tuple(_objective(o, f"--space {where}: objectives[{i}]")
                       for i, o in enumerate(data.get("objectives", [])))
    parameters = tuple(_parameter(p, f"--space {where}: parameters[{i}]")
                       for i, p in enumerate(data.get("parameters", [])))
    fixed = data.get("fixed", {})
    if not isinstance(fixed, dict):
        raise SpaceError(f"--space {where}: [fixed] must be a table of option = value")
    return Space(path=str(where), updater=updater, baseline=str(data.get("baseline", "")),
                 reference=str(data.get("reference", "octomap-cpp")), parameters=parameters,
                 objectives=objectives, sampler=name, text=text, fixed=dict(fixed), **numbers)


def _objective(raw: Any, where: str) -> Objective:
    if not isinstance(raw, dict):
        raise SpaceError(f"{where}: must be a table with name (and direction)")
    name = _need(raw, "name", str, where)
    if name not in OBJECTIVES:
        raise SpaceError(f"{where}: unknown objective {name!r} (known: "
                         f"{', '.join(OBJECTIVES)})")
    direction = raw.get("direction", OBJECTIVES[name][0])
    if direction not in DIRECTIONS:
        raise SpaceError(f"{where}: direction must be minimize or maximize, got {direction!r}")
    extra = set(raw) - {"name", "direction"}
    if extra:
        raise SpaceError(f"{where}: unknown entries {', '.join(sorted(extra))}")
    return Objective(name, direction)


def _parameter(raw: Any, where: str) -> Parameter:
    if not isinstance(raw, dict):
        raise SpaceError(f"{where}: must be a table")
    name = _need(raw, "name", str, where)
    where = f"{where} ({name})"
    target = raw.get("target", "updater")
    if target not in TARGETS:
        raise SpaceError(f"{where}: target must be shared or updater, got {target!r}")
    if target == "shared" and name not in SHARED_OPTIONS:
        raise SpaceError(f"{where}: a shared parameter is one of {', '.join(SHARED_OPTIONS)}")
    extra = set(raw) - {"name", "target", "default", "low", "high", "log", "step", "choices",
                        "type", "source"}
    if extra:
        raise SpaceError(f"{where}: unknown entries {', '.join(sorted(extra))}")
    if "default" not in raw:
        raise SpaceError(f"{where}: default is missing (the paper's value, the first trial's)")
    common = {"name": name, "target": target, "default": raw["default"],
              "source": str(raw.get("source", ""))}
    if "choices" in raw:
        choices = raw["choices"]
        if not isinstance(choices, list) or not choices:
            raise SpaceError(f"{where}: choices must be a non-empty list")
        if raw["default"] not in choices:
            raise SpaceError(f"{where}: the default {raw['default']!r} is not one of the choices")
        return Parameter(**common, choices=tuple(choices))
    low, high = _need(raw, "low", (int, float), where), _need(raw, "high", (int, float), where)
    integer = raw.get("type", "float") == "int"
    if raw.get("type", "float") not in ("int", "float"):
        raise SpaceError(f"{where}: type must be int or float (or give choices)")
    if not (math.isfinite(low) and math.isfinite(high) and low < high):
        raise SpaceError(f"{where}: the range [{low:g}, {high:g}] is empty (low must be below "
                         f"high)")
    log = bool(raw.get("log", False))
    if log and low <= 0:
        raise SpaceError(f"{where}: a log range needs low > 0, got {low}")
    step = raw.get("step")
    if step is not None and (isinstance(step, bool) or not isinstance(step, (int, float))
                             or step <= 0 or log):
        raise SpaceError(f"{where}: step must be a positive number (and not with log)")
    default = raw["default"]
    if isinstance(default, bool) or not isinstance(default, (int, float)) \
            or not low <= default <= high:
        raise SpaceError(f"{where}: the default {default!r} is outside [{low:g}, {high:g}]")
    return Parameter(**common, low=float(low), high=float(high), log=log,
                     step=None if step is None else float(step), integer=integer)


def check_space(space: Space) -> None:
    """The space against the registry: the updaters exist, every parameter and fixed option is
    one the explored updater takes (shared ones: at least one map of the trial takes it), the
    updater accepts every bound and default, and there is something to explore."""
    from evsmap.registry import UPDATERS

    where = f"--space {space.path}"
    if space.updater not in UPDATERS:
        raise SpaceError(f"{where}: updater {space.updater!r} is not registered "
                         f"(evsmap list: {', '.join(UPDATERS.names())})")
    if space.reference not in UPDATERS:
        raise SpaceError(f"{where}: reference {space.reference!r} is not a registered updater")
    if not space.parameters:
        raise SpaceError(f"{where}: the space is empty (no [[parameters]])")
    if not space.objectives:
        raise SpaceError(f"{where}: no [[objectives]] to steer by")
    names = [p.name for p in space.parameters]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise SpaceError(f"{where}: parameter {twice[0]!r} is given twice")
    taken = UPDATERS.get(space.updater).options
    for name in [*names, *space.fixed]:
        if name not in taken:
            raise SpaceError(f"{where}: {space.updater} has no option {name!r} (its options: "
                             f"{', '.join(taken)})")
    if set(names) & set(space.fixed):
        raise SpaceError(f"{where}: {sorted(set(names) & set(space.fixed))[0]!r} is both a "
                         f"parameter and [fixed]")
    objectives = [o.name for o in space.objectives]
    if "size_ratio" in objectives and not space.baseline:
        raise SpaceError(f"{where}: objective size_ratio needs a baseline")
    for p in space.parameters:
        for value in p.values_to_try():
            _try(space, {**space.defaults(), p.name: value}, where, p)


def _try(space: Space, params: dict[str, Any], where: str, p: Parameter) -> None:
    """Make the explored updater with ``params`` (no frame is integrated; the constructor
    checks its options)."""
    from evsmap.registry import UPDATERS

    shared, own = space.split(params)
    try:
        UPDATERS.create(space.updater, **shared, **own)
    except (EvsmapError, ValueError, TypeError) as exc:
        raise SpaceError(f"{where}: {p.name} = {params[p.name]!r} is refused by "
                         f"{space.updater}: {exc}") from None
