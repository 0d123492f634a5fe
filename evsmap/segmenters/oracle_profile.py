"""The oracle's noise models as data: a profile names every setting of
:class:`~evsmap.segmenters.oracle.OracleSegmenter` and says where its values came from.

Shipped profiles (``evsmap/segmenters/oracle_profiles/<name>.json``):

* ``fitted`` (the default): fitted to a trained network's errors on labelled frames by
  ``evsmap oracle fit`` (:mod:`evsmap.segmenters.oracle_fit`); the file holds the network's
  measured figures and the oracle's at the fitted settings (docs/oracle.md).
* ``per-pixel``: the model before 2026-11-29 (accuracy 0.85, boundary 0.55 within 3 px, every
  pixel's error drawn independently, a seeded confusion matrix): the same bytes as then.
* ``noise-free``: every labelled pixel's top-1 is its true class.

A user's fit is a JSON file in the same schema, named by its path (``-s profile=FILE``). Options
given to the segmenter override the profile's value of the same name.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from evsmap.errors import InvalidDataError
from evsmap.metrics.label_errors import KINDS

PROFILE_NAMES = ("fitted", "per-pixel", "noise-free")
"""The shipped profiles, by name."""
DEFAULT_PROFILE = "fitted"
SCHEMA = 1
CONFUSION_MODES = ("seeded", "adjacent", "fitted")
MEAN_TOP1_KINDS = KINDS
"""The kinds of pixel with a mean top-1 probability (the error figures' kinds)."""


@dataclass(frozen=True)
class OracleProfile:
    """Every setting of the oracle's noise model (module notes of :mod:`evsmap.segmenters.oracle`).

    Attributes:
        name: the profile's name (a shipped one) or the file it was read from.
        source: where the values come from, in words.
        accuracy: top-1 accuracy of a labelled pixel away from label boundaries.
        boundary_accuracy: the same within ``boundary_blur`` px of a boundary.
        boundary_blur: the boundary band's half-width (px, Chebyshev).
        boundary_across: share of the band's wrong pixels that take the label across the
            boundary (the rest take a confuser).
        class_accuracy, class_boundary_accuracy: per class (NYUv2-40 index), replacing the two
            above for that class.
        confusion: ``seeded`` (a random confusion matrix fixed by the seed), ``adjacent`` (the
            classes touching it in the frame) or ``fitted`` (``confusers``).
        confusers: per class, up to 3 ``[class, weight]`` pairs (fitted confusion).
        error_block: errors shared by squares of this many px (with ``error_scale`` 0).
        error_scale: the standard deviation (px at
            :data:`~evsmap.metrics.label_errors.REFERENCE_WIDTH` width, scaled with the frame: a
            network sees every frame at its own input size) of the Gaussian smoothing of the
            image's error field; 0: ``error_block``'s squares.
        world_share: share of the error field's variance anchored to the scene (a 3D field
            read at each pixel's point, so a surface seen wrong in one frame tends to be wrong
            in the next), the rest the image's own.
        world_scale: the 3D field's lattice spacing (m).
        true_second: probability that a wrong pixel's second class is its true class.
        mean_top1: mean top-1 probability per kind of pixel (:data:`MEAN_TOP1_KINDS`).
        concentration: the Beta concentration (a + b) of the top-1 probability.
        fit: the fit's figures (the network's and the oracle's), for the docs and the report.
    """

    name: str
    source: str
    accuracy: float
    boundary_accuracy: float
    boundary_blur: int = 3
    boundary_across: float = 1.0
    class_accuracy: dict[int, float] = field(default_factory=dict)
    class_boundary_accuracy: dict[int, float] = field(default_factory=dict)
    confusion: str = "seeded"
    confusers: dict[int, list[tuple[int, float]]] = field(default_factory=dict)
    error_block: int = 1
    error_scale: float = 0.0
    world_share: float = 0.0
    world_scale: float = 0.25
    true_second: float = 0.7
    mean_top1: dict[str, float] = field(default_factory=lambda: {
        "correct": 0.80, "wrong": 0.55, "edge_correct": 0.60, "edge_wrong": 0.50,
        "void": 0.30})
    concentration: float = 12.0
    fit: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _check(self)

    # -- identity ---------------------------------------------------------------------------
    def settings(self) -> dict[str, Any]:
        """Every value that decides a prediction (not the name, source or fit figures)."""
        out = dataclasses.asdict(self)
        for key in ("name", "source", "fit"):
            out.pop(key)
        return out

    def digest(self) -> str:
        """12 hex digits of the settings: the same settings, the same digest."""
        text = json.dumps(self.settings(), sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:12]

    def replace(self, **changes: Any) -> OracleProfile:
        """A copy with ``changes`` (checked like a loaded profile)."""
        return dataclasses.replace(self, **changes)

    # -- files ------------------------------------------------------------------------------
    def to_json(self) -> dict[str, Any]:
        out = {"schema": SCHEMA, **dataclasses.asdict(self)}
        out["class_accuracy"] = {str(k): v for k, v in self.class_accuracy.items()}
        out["class_boundary_accuracy"] = {str(k): v
                                          for k, v in self.class_boundary_accuracy.items()}
        out["confusers"] = {str(k): [list(p) for p in v] for k, v in self.confusers.items()}
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any], *, where: str) -> OracleProfile:
        if not isinstance(data, dict) or data.get("schema") != SCHEMA:
            raise InvalidDataError(f"{where}: not an oracle profile (schema {SCHEMA})")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known - {"schema"})
        if unknown:
            raise InvalidDataError(f"{where}: unknown oracle profile field(s) "
                                   f"{', '.join(unknown)}")
        values = {k: v for k, v in data.items() if k in known}
        try:
            values["class_accuracy"] = {int(k): float(v) for k, v in
                                        values.get("class_accuracy", {}).items()}
            values["class_boundary_accuracy"] = {
                int(k): float(v) for k, v in values.get("class_boundary_accuracy", {}).items()}
            values["confusers"] = {int(k): [(int(c), float(w)) for c, w in v]
                                   for k, v in values.get("confusers", {}).items()}
            return cls(**values)
        except (TypeError, ValueError) as exc:
            raise InvalidDataError(f"{where}: {exc}") from None

    def save(self, path: str | Path) -> Path:
        from evsmap.fileio import atomic_write_text

        path = Path(path)
        atomic_write_text(path, json.dumps(self.to_json(), indent=1) + "\n")
        return path


def _check(p: OracleProfile) -> None:
    def fraction(name: str, value: float) -> None:
        if not 0.0 <= float(value) <= 1.0:
            raise InvalidDataError(f"oracle profile {p.name}: {name} must lie in [0, 1], "
                                   f"got {value!r}")

    for name in ("accuracy", "boundary_accuracy", "boundary_across", "world_share",
                 "true_second"):
        fraction(name, getattr(p, name))
    for table in ("class_accuracy", "class_boundary_accuracy"):
        for cls, value in getattr(p, table).items():
            fraction(f"{table}[{cls}]", value)
    if p.confusion not in CONFUSION_MODES:
        raise InvalidDataError(f"oracle profile {p.name}: confusion must be one of "
                               f"{CONFUSION_MODES}, got {p.confusion!r}")
    if int(p.boundary_blur) < 0 or int(p.error_block) < 1:
        raise InvalidDataError(f"oracle profile {p.name}: boundary_blur must be >= 0 and "
                               f"error_block >= 1, got {p.boundary_blur!r}, {p.error_block!r}")
    if float(p.error_scale) < 0 or float(p.world_scale) <= 0:
        raise InvalidDataError(f"oracle profile {p.name}: error_scale must be >= 0 and "
                               f"world_scale > 0, got {p.error_scale!r}, {p.world_scale!r}")
    missing = set(MEAN_TOP1_KINDS) - set(p.mean_top1)
    if missing or not all(0.0 < float(v) < 1.0 for v in p.mean_top1.values()):
        raise InvalidDataError(f"oracle profile {p.name}: mean_top1 needs {MEAN_TOP1_KINDS} "
                               f"in (0, 1), got {p.mean_top1!r}")
    if float(p.concentration) <= 0:
        raise InvalidDataError(f"oracle profile {p.name}: concentration must be > 0")


def _shipped_path(name: str) -> Path:
    return Path(str(resources.files("evsmap.segmenters") / "oracle_profiles" / f"{name}.json"))


def load_profile(name_or_path: str | Path) -> OracleProfile:
    """A shipped profile by name (:data:`PROFILE_NAMES`), else a profile file; one line naming
    it when neither."""
    text = str(name_or_path)
    path = _shipped_path(text) if text in PROFILE_NAMES else Path(text).expanduser()
    if not path.is_file():
        raise InvalidDataError(f"oracle: profile {text!r} is neither one of "
                               f"{', '.join(PROFILE_NAMES)} nor a file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InvalidDataError(f"oracle: cannot read profile {path}: {exc}") from None
    profile = OracleProfile.from_json(data, where=str(path))
    return profile if text in PROFILE_NAMES else profile.replace(name=str(path))


__all__ = ["CONFUSION_MODES", "DEFAULT_PROFILE", "MEAN_TOP1_KINDS", "OracleProfile",
           "PROFILE_NAMES", "load_profile"]
