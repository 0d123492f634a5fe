"""Training recipes: every choice of a training run as data (a TOML file), validated field by
field.

A recipe is a flat TOML table whose keys are the fields of :class:`Recipe`. The recipes shipped
with evsmap live in ``evsmap/train/recipes/`` (``paper``: EVSMaP section IV-A; ``synth-proxy``:
evsmap's reduced recipe for the synthetic rooms); ``--recipe`` takes one of their names or a
path to a TOML file. A file may start from another recipe with ``base = "NAME-or-PATH"`` and
give only the fields it changes; without ``base`` it must give every field. Each command-line
flag (``--epochs``, ``--lr``, ...) and ``--set FIELD=VALUE`` then overrides one field.

Every problem is one line naming the recipe and the field (:class:`RecipeError`). No torch here.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any

from evsmap.errors import EvsmapError

SCHEDULES = ("poly", "constant")
OPTIMIZERS = ("sgd",)
INPUT = "input"
"""``crop = "input"``: crop to the network's input size (what ``evsmap eval`` resizes frames
to)."""


class RecipeError(EvsmapError):
    """A recipe that cannot be read or has an invalid field (one line naming it)."""


@dataclass(frozen=True)
class Recipe:
    """Every training choice of a run. See ``docs/training.md`` for each field's meaning and the
    sentence of the paper it comes from."""

    name: str
    description: str
    source: str
    # optimisation
    epochs: int
    batch_size: int
    optimizer: str
    lr: float
    momentum: float
    weight_decay: float
    nesterov: bool
    # learning-rate schedule
    schedule: str
    poly_power: float
    poly_start_epoch: int
    poly_restart: bool
    # augmentation
    crop: str | tuple[int, int]
    scale: tuple[float, float]
    flip: float
    # loss
    alpha: float
    beta: float
    label_smoothing: float
    side_weight: float
    # run
    sync_bn: bool
    amp: bool
    seed: int
    workers: int
    eval_every: int

    # -- conversions ------------------------------------------------------------------------
    def as_dict(self) -> dict[str, Any]:
        """Plain values (lists for pairs), as in a TOML file; JSON- and ``weights_only``-safe."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            out[f.name] = list(value) if isinstance(value, tuple) else value
        return out

    def to_toml(self) -> str:
        """The recipe as a TOML file that :func:`load_recipe` reads back to an equal recipe."""
        lines = []
        for key, value in self.as_dict().items():
            lines.append(f"{key} = {_toml_value(value)}")
        return "\n".join(lines) + "\n"

    def replace(self, **changes: Any) -> Recipe:
        """A copy with ``changes`` applied and validated (a :class:`RecipeError` names the
        field)."""
        data = self.as_dict()
        for key in changes:
            if key not in data:
                raise RecipeError(f"recipe {self.name}: unknown field {key!r} "
                                  f"(fields: {', '.join(field_names())})")
        data.update(changes)
        return recipe_from_dict(data, where=f"recipe {self.name}")

    def crop_size(self, input_size: tuple[int, int]) -> tuple[int, int]:
        """The crop (H, W): the network input size for ``crop = "input"``."""
        return tuple(input_size) if self.crop == INPUT else tuple(self.crop)  # type: ignore

    def lr_factor(self, epoch: int) -> float:
        """The learning-rate multiplier of 0-based ``epoch`` (see :func:`poly_factor`)."""
        if self.schedule == "constant":
            return 1.0
        return poly_factor(epoch, epochs=self.epochs, start=self.poly_start_epoch,
                           power=self.poly_power, restart=self.poly_restart)

    def lr_at(self, epoch: int) -> float:
        return self.lr * self.lr_factor(epoch)


def poly_factor(epoch: int, *, epochs: int, start: int, power: float, restart: bool) -> float:
    """Learning-rate multiplier of the 0-based ``epoch`` under the paper's schedule.

    Epochs ``0 .. start-1`` run at the initial rate (factor 1). From epoch ``start`` on:

    * ``restart = False`` (the literal reading, the default): ``(1 - epoch / epochs) ** power``,
      the formula of section IV-A with ``ep`` the epoch index and ``max_ep`` the total, so the
      rate drops at ``start`` from 1 to ``(1 - start / epochs) ** power`` (0.7254 at 150/500);
    * ``restart = True``: ``(1 - (epoch - start) / (epochs - start)) ** power``, the polynomial
      counted from ``start``, continuous at ``start``.

    Both stay above zero in the last epoch (``epoch = epochs - 1``).
    """
    if epoch < start:
        return 1.0
    if restart:
        return (1.0 - (epoch - start) / (epochs - start)) ** power
    return (1.0 - epoch / epochs) ** power


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return str(value)


def field_names() -> list[str]:
    return [f.name for f in fields(Recipe)]


# -- validation -----------------------------------------------------------------------------------

def _number(where: str, key: str, value: Any, *, low: float, low_open: bool = False,
            high: float = math.inf, high_open: bool = False, integer: bool = False) -> Any:
    kind = "an integer" if integer else "a number"
    if isinstance(value, bool) or not isinstance(value, (int, float)) or \
            (integer and not isinstance(value, int)):
        raise RecipeError(f"{where}: {key} must be {kind}, got {value!r}")
    if not integer:
        try:
            value = float(value)
        except OverflowError:  # an integer beyond the float range
            raise RecipeError(f"{where}: {key} must be finite, got {value!r}") from None
    if isinstance(value, float) and not math.isfinite(value):
        raise RecipeError(f"{where}: {key} must be finite, got {value!r}")
    below = value <= low if low_open else value < low
    above = value >= high if high_open else value > high
    if below or above:
        lo = ("(" if low_open else "[") + f"{low:g}"
        hi = (f"{high:g}" + (")" if high_open else "]")) if math.isfinite(high) else "inf)"
        raise RecipeError(f"{where}: {key} must be {kind} in {lo}, {hi}, got {value!r}")
    return int(value) if integer else float(value)


def _boolean(where: str, key: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise RecipeError(f"{where}: {key} must be true or false, got {value!r}")
    return value


def _text(where: str, key: str, value: Any, choices: tuple[str, ...] | None = None) -> str:
    if not isinstance(value, str):
        raise RecipeError(f"{where}: {key} must be a string, got {value!r}")
    if choices is not None and value not in choices:
        raise RecipeError(f"{where}: {key} must be one of {', '.join(choices)}, got {value!r}")
    return value


def _pair(where: str, key: str, value: Any, what: str) -> list:
    if isinstance(value, str) or not isinstance(value, (list, tuple)) or len(value) != 2:
        raise RecipeError(f"{where}: {key} must be {what}, got {value!r}")
    return list(value)


def parse_size(text: str) -> tuple[int, int]:
    """``"HxW"`` (e.g. ``480x640``) as ``(H, W)``; :class:`ValueError` otherwise."""
    parts = str(text).lower().replace(" ", "").split("x")
    if len(parts) != 2 or not all(p.isdigit() for p in parts) or min(map(int, parts)) < 1:
        raise ValueError(f"expected HxW with positive integers (e.g. 480x640), got {text!r}")
    return int(parts[0]), int(parts[1])


def recipe_from_dict(data: Mapping[str, Any], *, where: str = "recipe") -> Recipe:
    """A validated :class:`Recipe` from plain values (every field given, no other key)."""
    names = field_names()
    unknown = [k for k in data if k not in names]
    if unknown:
        raise RecipeError(f"{where}: unknown field {unknown[0]!r} (fields: {', '.join(names)})")
    absent = [k for k in names if k not in data]
    if absent:
        raise RecipeError(f"{where}: field {absent[0]!r} missing (give every field, or start "
                          f"from another recipe with base = \"paper\")")
    d = dict(data)
    out: dict[str, Any] = {}
    for key in ("name", "description", "source"):
        out[key] = _text(where, key, d[key])
    if not out["name"].strip():
        raise RecipeError(f"{where}: name must not be empty")
    out["epochs"] = _number(where, "epochs", d["epochs"], low=1, integer=True)
    out["batch_size"] = _number(where, "batch_size", d["batch_size"], low=1, integer=True)
    out["optimizer"] = _text(where, "optimizer", d["optimizer"], OPTIMIZERS)
    out["lr"] = _number(where, "lr", d["lr"], low=0, low_open=True)
    out["momentum"] = _number(where, "momentum", d["momentum"], low=0, high=1, high_open=True)
    out["weight_decay"] = _number(where, "weight_decay", d["weight_decay"], low=0)
    out["nesterov"] = _boolean(where, "nesterov", d["nesterov"])
    if out["nesterov"] and out["momentum"] == 0:
        raise RecipeError(f"{where}: nesterov needs momentum > 0")
    out["schedule"] = _text(where, "schedule", d["schedule"], SCHEDULES)
    out["poly_power"] = _number(where, "poly_power", d["poly_power"], low=0, low_open=True)
    out["poly_start_epoch"] = _number(where, "poly_start_epoch", d["poly_start_epoch"], low=0,
                                      integer=True)
    out["poly_restart"] = _boolean(where, "poly_restart", d["poly_restart"])
    out["crop"] = _crop(where, d["crop"])
    out["scale"] = _scale(where, d["scale"])
    out["flip"] = _number(where, "flip", d["flip"], low=0, high=1)
    out["alpha"] = _number(where, "alpha", d["alpha"], low=0)
    out["beta"] = _number(where, "beta", d["beta"], low=0)
    if out["alpha"] == 0 and out["beta"] == 0:
        raise RecipeError(f"{where}: alpha and beta are both 0: the loss would be 0")
    out["label_smoothing"] = _number(where, "label_smoothing", d["label_smoothing"], low=0,
                                     high=1, high_open=True)
    out["side_weight"] = _number(where, "side_weight", d["side_weight"], low=0)
    out["sync_bn"] = _boolean(where, "sync_bn", d["sync_bn"])
    out["amp"] = _boolean(where, "amp", d["amp"])
    out["seed"] = _number(where, "seed", d["seed"], low=0, high=2**63 - 1, integer=True)
    out["workers"] = _number(where, "workers", d["workers"], low=0, integer=True)
    out["eval_every"] = _number(where, "eval_every", d["eval_every"], low=0, integer=True)
    return Recipe(**out)


def _crop(where: str, crop: Any) -> str | tuple[int, int]:
    """The recipe's ``crop``: ``"input"``, or (H, W) from ``[H, W]`` or ``"HxW"``."""
    if isinstance(crop, str):
        if crop != INPUT:
            try:
                crop = parse_size(crop)
            except ValueError:
                raise RecipeError(f"{where}: crop must be \"{INPUT}\" (the network's input "
                                  f"size), [H, W] or \"HxW\", got {crop!r}") from None
    if crop == INPUT:
        return INPUT
    h, w = _pair(where, "crop", crop, f"\"{INPUT}\" or [H, W]")
    return (_number(where, "crop[0] (height)", h, low=1, integer=True),
            _number(where, "crop[1] (width)", w, low=1, integer=True))


def _scale(where: str, scale: Any) -> tuple[float, float]:
    """The recipe's ``scale``: [min, max] with 0 < min <= max."""
    lo, hi = _pair(where, "scale", scale, "[min, max]")
    lo = _number(where, "scale[0] (min)", lo, low=0, low_open=True)
    hi = _number(where, "scale[1] (max)", hi, low=0, low_open=True)
    if lo > hi:
        raise RecipeError(f"{where}: scale must be [min, max] with min <= max, got "
                          f"{list(scale)!r}")
    return (lo, hi)


# -- files ---------------------------------------------------------------------------------------

def shipped_recipes() -> list[str]:
    """Names of the recipes shipped with evsmap."""
    folder = resources.files("evsmap.train") / "recipes"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def _read_toml(text: str, where: str) -> dict[str, Any]:
    try:
        return tomllib.loads(text)
    except ValueError as exc:  # TOMLDecodeError, or an integer of more than 4300 digits
        raise RecipeError(f"{where}: not valid TOML ({exc})") from None
    except RecursionError:
        raise RecipeError(f"{where}: not valid TOML (nested too deeply)") from None


def _source(name_or_path: str | Path) -> tuple[str, str]:
    """(text, where) of a shipped recipe name or a TOML file."""
    text = str(name_or_path)
    path = Path(text)
    if path.suffix == ".toml" or path.exists() or "/" in text:
        if not path.is_file():
            raise RecipeError(f"{path}: recipe file not found")
        try:
            return path.read_text(), str(path)
        except (OSError, UnicodeDecodeError) as exc:
            raise RecipeError(f"{path}: cannot read the recipe ({exc})") from None
    known = shipped_recipes()
    if text not in known:
        raise RecipeError(f"unknown recipe {text!r} (shipped: {', '.join(known)}; or give a "
                          f"FILE.toml)")
    resource = resources.files("evsmap.train") / "recipes" / f"{text}.toml"
    return resource.read_text(), f"recipe {text}"


def load_recipe(name_or_path: str | Path = "paper", *, _seen: tuple[str, ...] = ()) -> Recipe:
    """A shipped recipe by name or a TOML file, with its ``base`` chain resolved, validated."""
    text, where = _source(name_or_path)
    if where in _seen:
        raise RecipeError(f"{where}: base recipes form a loop ({' -> '.join(_seen)})")
    data = _read_toml(text, where)
    base = data.pop("base", None)
    if base is not None:
        if not isinstance(base, str):
            raise RecipeError(f"{where}: base must be a recipe name or file, got {base!r}")
        if "/" in base or base.endswith(".toml"):
            src = Path(str(name_or_path))
            if src.exists() and not Path(base).is_absolute():
                base = str(src.parent / base)
        try:
            merged = load_recipe(base, _seen=(*_seen, where)).as_dict()
        except RecipeError as exc:  # the user gave this file: name it, then the base's problem
            inner = "".join(c if c.isprintable() else repr(c)[1:-1] for c in str(exc))
            raise RecipeError(f"{where}: base {base!r}: {inner}") from None
        merged.update(data)
        data = merged
    for key, value in data.items():
        if isinstance(value, dict):
            raise RecipeError(f"{where}: {key} is a table; a recipe is flat key = value pairs")
    return recipe_from_dict(data, where=where)


def apply_overrides(recipe: Recipe, overrides: Mapping[str, Any]) -> Recipe:
    """``recipe`` with each override (field -> value) applied; values from the command line may
    be strings (``"480x640"`` for crop, ``"0.5,2"`` for scale)."""
    if not overrides:
        return recipe
    changes: dict[str, Any] = {}
    kinds = {f.name: f.type for f in fields(Recipe)}
    for key, value in overrides.items():
        if key not in kinds:
            raise RecipeError(f"unknown recipe field {key!r} (fields: {', '.join(field_names())})")
        if key == "scale" and isinstance(value, str):
            parts = value.replace(" ", "").split(",")
            try:
                value = [float(p) for p in parts]
            except ValueError:
                raise RecipeError(f"scale must be MIN,MAX (e.g. 0.5,2.0), got {value!r}") from None
        elif key in ("lr", "momentum", "weight_decay", "poly_power", "flip", "alpha", "beta",
                     "label_smoothing", "side_weight") and isinstance(value, int) \
                and not isinstance(value, bool):
            value = float(value)
        changes[key] = value
    return recipe.replace(**changes)


def differences(a: Recipe, b: Recipe) -> dict[str, tuple[Any, Any]]:
    """Fields whose values differ: name -> (a's, b's)."""
    da, db = a.as_dict(), b.as_dict()
    return {k: (da[k], db[k]) for k in da if da[k] != db[k]}


__all__ = ["INPUT", "Recipe", "RecipeError", "apply_overrides", "differences", "field_names",
           "load_recipe", "parse_size", "poly_factor", "recipe_from_dict", "shipped_recipes"]
