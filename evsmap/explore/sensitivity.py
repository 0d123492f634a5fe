"""How a study's answer moves with the labels: its key points (the paper's point, and the best
trial within the mIoU-loss tolerance, else the largest size ratio: what the report's answer
names) mapped again, with their paired baselines, under each label source - the oracle's
shipped profiles (``per-pixel``, ``fitted``, ``noise-free``), the study's own segmenter, and a
trained network given for the purpose. The study itself is never run again.

A record per (key point, label source): the trial's and its baseline's map size and scene mIoU
under those labels, the size ratio, the mIoU loss and whether the point meets the answer's
criterion there (a smaller map at no more than :data:`~evsmap.explore.results.MIOU_LOSS_POINTS`
lost). Records are stored in the study (its user attribute :data:`ATTR`), keyed by the trial
and the labels' identity, so a resumed or re-reported study reads them back; the maps behind
them are kept in evsmap's cache beside the paired baselines
(:meth:`~evsmap.explore.bench.Bench.labelled_map`).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from evsmap.errors import EvsmapError
from evsmap.explore.bench import Bench, Inputs, baseline_updater
from evsmap.explore.results import MIOU_LOSS_POINTS, Answer, answer, trial_rows

if TYPE_CHECKING:
    import optuna

ATTR = "evsmap_sensitivity"
"""The study's user attribute holding the sensitivity's network and its records."""
VERSION = 2
"""Bumped when what a stored record holds changes (older records are measured again)."""
ORACLE_CARRIED = ("seed", "k", "num_classes")
"""The study's oracle options every profile source keeps (the rest are the noise model's, which
each profile sets)."""


class SensitivityError(EvsmapError):
    """A sensitivity option that cannot be used (one line)."""


@dataclass(frozen=True)
class Source:
    """One labelling of the frames.

    Attributes:
        name: what the report calls it (``oracle per-pixel``, ``feagnet-v1 (best.pt)``).
        segmenter, options, weights: the segmenter making the labels.
        study: the study's own trials were mapped with these labels.
    """

    name: str
    segmenter: str
    options: dict[str, Any] = field(default_factory=dict)
    weights: str | None = None
    study: bool = False

    def inputs(self, base: Inputs) -> Inputs:
        return dataclasses.replace(base, segmenter=self.segmenter,
                                   segmenter_options=dict(self.options), weights=self.weights)


@dataclass(frozen=True)
class Network:
    """A trained network given for the sensitivity (``--sensitivity-weights``)."""

    segmenter: str
    weights: str

    def source(self) -> Source:
        return Source(f"{self.segmenter} ({Path(self.weights).name})", self.segmenter,
                      weights=self.weights)


@dataclass(frozen=True)
class KeyPoint:
    """A trial the answer names, and the roles it plays there."""

    trial: int
    roles: tuple[str, ...]

    @property
    def role(self) -> str:
        return "; ".join(self.roles)


PAPER_POINT = "the paper's point"
BEST_POINT = f"the best within {MIOU_LOSS_POINTS:g} pt"
LARGEST_POINT = "the largest size ratio"


def key_points(found: Answer) -> list[KeyPoint]:
    """The trials the answer names: the paper's point, and the best smaller map within the
    tolerance (none there: the largest size ratio of any trial); one point per trial."""
    named: list[tuple[str, dict[str, Any] | None]] = [(PAPER_POINT, found.default)]
    named.append((BEST_POINT, found.best) if found.best is not None
                 else (LARGEST_POINT, found.best_any))
    points: dict[int, list[str]] = {}
    for role, row in named:
        if row is not None:
            points.setdefault(int(row["number"]), []).append(role)
    return [KeyPoint(n, tuple(roles)) for n, roles in points.items()]


def applies(inputs: Inputs, has_truth: bool) -> str | None:
    """Why a study gets no sensitivity by default (``None``: it does): it needs the ground
    truth's voxels (and frame labels, for the oracle), and a study labelled by the oracle or a
    network."""
    if not has_truth:
        return f"{inputs.sequence} has no ground-truth voxels to score labels against"
    if inputs.segmenter != "oracle" and inputs.weights is None:
        return (f"the study's segmenter {inputs.segmenter} is neither the oracle nor a network "
                f"with weights")
    return None


def label_sources(bench: Bench, network: Network | None = None) -> list[Source]:
    """The oracle's shipped profiles (with the study's seed, k and class count), the study's
    own labels where they are none of those, and ``network``; the source whose labels are the
    study's is marked."""
    from evsmap.segmenters.oracle_profile import PROFILE_NAMES

    inputs = bench.inputs
    carried = ({k: v for k, v in inputs.segmenter_options.items() if k in ORACLE_CARRIED}
               if inputs.segmenter == "oracle" else {})
    sources = [Source(f"oracle {name}", "oracle", {**carried, "profile": name})
               for name in PROFILE_NAMES]
    if network is not None:
        sources.append(network.source())
    own = bench.observations_key()
    marked = [dataclasses.replace(s, study=True) if _key(bench, s) == own else s
              for s in sources]
    if not any(s.study for s in marked):
        marked.insert(0, Source(_own_name(bench), inputs.segmenter,
                                dict(inputs.segmenter_options), inputs.weights, study=True))
    return marked


def _key(bench: Bench, source: Source) -> dict[str, Any]:
    return bench.relabelled(source.inputs(bench.inputs)).observations_key()


def _own_name(bench: Bench) -> str:
    """The study's labels by name: the oracle's profile (with the options it overrides), or
    the network and its weights file."""
    inputs = bench.inputs
    if inputs.weights is not None:
        return f"{inputs.segmenter} ({Path(inputs.weights).name})"
    from evsmap.measure.engine import is_oracle

    segmenter = bench.segmenter()
    return f"oracle {segmenter.profile.name}" if is_oracle(segmenter) else inputs.segmenter


def labels_id(bench: Bench, source: Source) -> str:
    """16 hex digits naming ``source``'s labels of the study's frames (a trial records its
    own: :meth:`~evsmap.explore.bench.Bench.labels_id`)."""
    return bench.relabelled(source.inputs(bench.inputs)).labels_id()


def point_sources(sources: list[Source], ids: dict[str, str],
                  made_with: str | None) -> list[tuple[Source, str]]:
    """A key point's sources and their labels' ids. The study's labels are those its trial
    recorded (``made_with``): where no source gives them today (the profile, the weights or the
    segmenters' code changed since), they are one more source, read from the trial. A trial
    that recorded none (a study made before it did) takes today's match (``sources``'s mark)."""
    if made_with is None:
        return [(s, ids[s.name]) for s in sources]
    out = [(dataclasses.replace(s, study=ids[s.name] == made_with), ids[s.name])
           for s in sources]
    if not any(s.study for s, _ in out):
        own = next((s for s in sources if s.study), sources[0])
        then = dataclasses.replace(own, name=f"the study's labels ({own.name}, when its "
                                             f"trials ran)", study=True)
        out.insert(0, (then, made_with))
    return out


# ---- stored in the study
def stored(study: optuna.Study) -> dict[str, Any]:
    """The study's sensitivity attribute: ``network`` (a :class:`Network` as a dict, or None)
    and ``records`` (key -> record)."""
    raw = study.user_attrs.get(ATTR)
    if not isinstance(raw, dict) or raw.get("version") != VERSION:
        return {"version": VERSION, "network": None, "records": {}}
    return raw


def stored_network(study: optuna.Study) -> Network | None:
    network = stored(study).get("network")
    return Network(**network) if isinstance(network, dict) else None


def _save(study: optuna.Study, data: dict[str, Any]) -> None:
    study.set_user_attr(ATTR, data)


# ---- measuring
def measure_point(bench: Bench, source: Source, record: dict[str, Any]) -> dict[str, Any]:
    """The trial whose stored ``record`` is given, and its paired baseline, mapped with
    ``source``'s labels: sizes, scene mIoU, size ratio and mIoU loss."""
    space = bench.space
    shared = dict(record["shared"])
    own = {k: v for k, v in record["params"].items() if k not in shared}
    labelled = bench.relabelled(source.inputs(bench.inputs))
    trial = labelled.labelled_map(space.updater, {**shared, **own}, shared)
    component = baseline_updater(space.baseline)
    base = labelled.labelled_map(component.name, {**component.config, **shared}, shared)
    return point_record(trial, base)


def point_record(trial: dict[str, Any], baseline: dict[str, Any]) -> dict[str, Any]:
    """A key point's figures under one labelling, from its map's and its baseline's records."""
    ratio = baseline["map_size"] / trial["map_size"]
    miou, base_miou = trial.get("scene_miou"), baseline.get("scene_miou")
    loss = None if miou is None or base_miou is None else 100.0 * (base_miou - miou)
    return {"map_size": trial["map_size"], "baseline_map_size": baseline["map_size"],
            "size_ratio": ratio, "scene_miou": miou, "baseline_scene_miou": base_miou,
            "miou_loss": loss, "smaller": ratio > 1.0,
            "within": loss is not None and loss <= MIOU_LOSS_POINTS,
            "meets": ratio > 1.0 and loss is not None and loss <= MIOU_LOSS_POINTS}


def _from_study(record: dict[str, Any]) -> dict[str, Any]:
    """The study's own figures of a trial (its labels are the study's: nothing to map)."""
    return point_record(record, record["baseline"])


def run_sensitivity(study: optuna.Study, bench: Bench, *, network: Network | None = None,
                    say: Callable[[str], None] = lambda line: None) -> list[dict[str, Any]]:
    """Every (key point, label source) record of ``study``: read from the study where stored,
    else measured and stored (one at a time, so an interruption keeps those done). ``network``
    replaces the study's stored sensitivity network (``None``: the stored one, if any)."""
    if not bench.space.baseline:
        return []
    data = stored(study)
    if network is not None:
        data["network"] = dataclasses.asdict(network)
        _save(study, data)
    network = stored_network(study) if network is None else network
    sources = label_sources(bench, network)
    ids = {s.name: labels_id(bench, s) for s in sources}  # once: the code may change meanwhile
    trials = {t.number: t for t in study.get_trials(deepcopy=False)}
    out = []
    for point in key_points(answer(trial_rows(study))):
        record = trials[point.trial].user_attrs["record"]
        for source, labels in point_sources(sources, ids, record.get("labels")):
            key = f"{point.trial}:{labels}"
            if key not in data["records"]:
                data["records"][key] = _measured(bench, source, record, point, say)
                _save(study, data)
            out.append({**data["records"][key], "trial": point.trial, "point": point.role,
                        "source": source.name, "study_labels": source.study,
                        "profile": _profile(bench, source)})
    return out


def _measured(bench: Bench, source: Source, record: dict[str, Any], point: KeyPoint,
              say: Callable[[str], None]) -> dict[str, Any]:
    start = time.perf_counter()
    if source.study:
        figures = {**_from_study(record), "from": "the study's trial"}
    else:
        say(f"labels: trial {point.trial} ({point.role}) with {source.name}'s labels")
        figures = {**measure_point(bench, source, record), "from": "mapped"}
    return {**figures, "segmenter": source.segmenter, "options": dict(source.options),
            "weights": source.weights, "wall_s": time.perf_counter() - start}


def _profile(bench: Bench, source: Source) -> str | None:
    """The oracle profile's name (with the options it overrides) ``source``'s labels came
    from, else ``None``."""
    if source.segmenter != "oracle":
        return None
    profile = bench.relabelled(source.inputs(bench.inputs)).segmenter().profile
    return str(profile.name)


def check_network(segmenter: str | None, weights: Path) -> Network:
    """The ``--sensitivity-weights`` network: the file must exist; its segmenter is
    ``segmenter``, else the model its card names (:class:`SensitivityError`, one line)."""
    from evsmap.registry import SEGMENTERS

    if not weights.is_file():
        raise SensitivityError(f"--sensitivity-weights {weights}: no such file")
    if segmenter is None:
        from evsmap.segmenters.cards import card_get, inspect_weights

        info = inspect_weights(weights)
        segmenter = card_get(info.card, "model")
        if not isinstance(segmenter, str) or not segmenter:
            raise SensitivityError(f"--sensitivity-weights {weights}: no card names its model; "
                                   f"give --sensitivity-segmenter NAME")
    if segmenter not in SEGMENTERS:
        raise SensitivityError(f"--sensitivity-segmenter {segmenter}: not a registered "
                               f"segmenter (evsmap list)")
    if not SEGMENTERS.get(segmenter).takes.weights:
        raise SensitivityError(f"--sensitivity-segmenter {segmenter}: not a network (it takes "
                               f"no weights)")
    return Network(segmenter, str(weights.resolve()))


__all__ = ["ATTR", "KeyPoint", "Network", "SensitivityError", "Source", "applies",
           "check_network", "key_points", "label_sources", "labels_id", "measure_point",
           "point_sources",
           "point_record", "run_sensitivity", "stored", "stored_network"]
