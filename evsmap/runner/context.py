"""What a run has to work with: where the data, weights and caches are, which sequences it maps,
and which requirements (datasets, weights, hardware) are satisfied on this machine."""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

from evsmap.measure.timing_policy import QUICK_POLICY, TimingPolicy
from evsmap.paths import REPO_ROOT, default_data_root
from evsmap.segmenters.oracle_profile import DEFAULT_PROFILE

SYNTHETIC_LABELS = ("oracle", "network")
"""What labels the synthetic room's semantic runs (:attr:`RunContext.synthetic_labels`)."""

SEGMENTATION_DATASETS = ("nyuv2", "sunrgbd", "cityscapes")
"""Datasets prepared with ``evsmap datasets prepare``, looked up as folders."""

MAPPING_SEQUENCES: dict[str, dict[str, Any]] = {
    # Table IV's Seq.1..5 (inferred, see paper_tables.toml) and where a user puts each: a TUM
    # folder, or a bag file / ROS2 bag folder read with the reader preset named here
    "tum": {"names": ("tum", "tum_fr1_xyz"), "reader": "tum", "options": {}},
    "rtabmap": {"names": ("rtabmap", "rtabmap.bag", "rtabmap_demo.bag"), "reader": "rosbag",
                "options": {"preset": "rtabmap"}},
    "asl": {"names": ("asl", "asl.bag", "cow_and_lady.bag", "data.bag"), "reader": "rosbag",
            "options": {"preset": "asl"}},
    "ours1": {"names": ("ours1", "ours1.bag"), "reader": "rosbag", "options": {"preset": "zed2i"}},
    "ours2": {"names": ("ours2", "ours2.bag"), "reader": "rosbag", "options": {"preset": "zed2i"}},
}


LONG_SYNTHETIC: dict[str, Any] = {"scene": "living_room", "seed": 0, "frames": 640, "laps": 4,
                                  "width": 640, "height": 480, "noise": True}
"""``--extended``: the long synthetic sequence (4 laps of the room, 640 frames, with revisits)."""
EXTENDED_RESOLUTIONS = (0.05,)
"""``--extended``: voxel sizes mapped beside Table IV's (OctoMap's customary 5 cm)."""


@dataclass
class RunContext:
    """Settings of one run, passed to every cell (picklable).

    Attributes:
        out: the run folder (records, artifacts, cache).
        data_root: where datasets and sequences are looked up (besides ``datasets/`` in the
            repository and ``../shared/data``).
        weights_dir: trained weights: ``<segmenter spec>@<dataset>.pt``, any file whose card
            is for the cell (:meth:`weights_choice`), or ``<segmenter name>@<dataset>.pt``.
        quick: smoke-test settings (fewer frames and runs, smaller synthetic frames, torch
            backend for speed).
        synthetic: options of the built-in synthetic sequence.
        synthetic_long: options of the long synthetic sequence (several laps of the room with
            revisits, as a robot's run; mapped by ``--extended`` runs), or None.
        frames: frames mapped per sequence (None: all).
        speed_backend, threads: the speed method.
        timing: the speed cells' timing rule, the fields of a
            :class:`~evsmap.measure.timing_policy.TimingPolicy` (:meth:`timing_policy`): the
            same for every row.
        speed_runs: timed passes of each of the two networks the int8 row compares.
        strict_timing: refuse to time on a busy machine: a cell whose calibration shows
            contention is retried once after a pause, then recorded as not measured.
        resolution: Table IV's voxel size (the paper gives none: semantic_slam's default 2 cm
            is assumed).
        resolutions_beside: further voxel sizes every Table IV system maps (the extra
            section): OctoMap's customary 5 cm with ``--extended``, else none.
        reference_on_synthetic: the C++ OctoMap reference row also maps the built-in synthetic
            sequences (``--extended``; it maps the real ones always).
        scannet_scenes: the ScanNet scenes the semantic-detail section maps (empty: the first
            of the validation split found, :mod:`evsmap.runner.scannet`).
        scannet_step: every how many frames of a ScanNet scene are mapped (30 Hz recordings).
        device: where the speed cells time the networks (``cpu``, ``cuda:N``; ``reproduce
            --device``): on a GPU with the torch backend, each pass between CUDA events
            (:func:`evsmap.measure.speed.measure_speed`); the map updates stay on the CPU.
        oracle: the oracle segmenter's options besides its profile (its seed).
        oracle_profile: the oracle's profile where it stands in for a network (``reproduce
            --oracle-profile``): a name of
            :data:`~evsmap.segmenters.oracle_profile.PROFILE_NAMES` or a profile file.
        synthetic_labels: what labels the semantic runs on the built-in synthetic sequences
            where their network has no NYUv2 weights (``reproduce --synthetic-labels``):
            ``oracle`` (with ``oracle_profile``) or ``network`` (a trained proxy network's own,
            :func:`evsmap.runner.mapping_plan.proxy_source`).
    """

    out: str
    data_root: str | None = None
    weights_dir: str | None = None
    quick: bool = False
    synthetic: dict[str, Any] = field(default_factory=lambda: {
        "scene": "living_room", "seed": 0, "frames": 60, "width": 640, "height": 480,
        "noise": True})
    synthetic_long: dict[str, Any] | None = None
    frames: int | None = None
    speed_runs: int = 10
    speed_backend: str = "onnxruntime"
    threads: int = field(default_factory=lambda: os.cpu_count() or 1)
    timing: dict[str, Any] = field(default_factory=lambda: TimingPolicy().as_dict())
    strict_timing: bool = False
    resolution: float = 0.02
    resolutions_beside: tuple[float, ...] = ()
    reference_on_synthetic: bool = False
    oracle: dict[str, Any] = field(default_factory=lambda: {"seed": 0})
    scannet_scenes: tuple[str, ...] = ()
    scannet_step: int = 10
    device: str = "cpu"
    oracle_profile: str = DEFAULT_PROFILE
    synthetic_labels: str = "oracle"

    @classmethod
    def create(cls, out: str | Path, *, data_root: str | Path | None = None,
               weights_dir: str | Path | None = None, quick: bool = False,
               strict_timing: bool = False, extended: bool = False) -> RunContext:
        """The context of a run; ``extended`` adds the long synthetic sequence, the 5 cm
        voxel size and the C++ OctoMap reference on the synthetic room to Table IV's mapping
        (not with ``quick``; not timed as a whole: 33 more runs, 16 of them of 640
        frames, where EVSMap's update alone takes about 0.35 s a frame at 2 cm on 2 cores)."""
        root = Path(data_root) if data_root else default_data_root()
        ctx = cls(out=str(out), data_root=str(root) if root else None,
                  weights_dir=str(weights_dir) if weights_dir else None, quick=quick,
                  strict_timing=strict_timing)
        if extended and not quick:
            ctx.synthetic_long = dict(LONG_SYNTHETIC)
            ctx.resolutions_beside = EXTENDED_RESOLUTIONS
            ctx.reference_on_synthetic = True
        if quick:
            ctx.synthetic.update(frames=8, width=320, height=240)
            ctx.frames = 8
            ctx.speed_runs, ctx.speed_backend = 3, "torch"
            ctx.timing = QUICK_POLICY.as_dict()
        return ctx

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def use_device(self, device: str) -> None:
        """Time the networks on ``device``: on a GPU with the torch backend (CUDA events; ONNX
        Runtime's CPU export is the CPU's method)."""
        from evsmap.devices import device_name

        self.device = device_name(device)
        if self.device != "cpu":
            self.speed_backend = "torch"

    def timing_policy(self) -> TimingPolicy:
        """The speed cells' timing rule."""
        return TimingPolicy(**self.timing)

    def resolutions(self) -> list[float]:
        """Table IV's voxel size, then those mapped beside it."""
        return [self.resolution, *(v for v in self.resolutions_beside if v != self.resolution)]

    # -- where things are -------------------------------------------------------------------
    def roots(self) -> list[Path]:
        roots = []
        if self.data_root:
            roots.append(Path(self.data_root))
        roots.append(REPO_ROOT / "datasets")
        roots.append(Path.cwd() / "datasets")
        seen, out = set(), []
        for r in roots:
            key = str(r.resolve()) if r.exists() else str(r)
            if key not in seen:
                seen.add(key)
                out.append(r)
        return out

    def dataset_path(self, name: str) -> Path | None:
        """The prepared dataset (or mapping sequence) ``name``, if present."""
        from evsmap.errors import EvsmapError
        from evsmap.readers.detect import detect_reader

        names = MAPPING_SEQUENCES[name]["names"] if name in MAPPING_SEQUENCES else (name,)
        for root in self.roots():
            for n in names:
                path = root / n
                if not path.exists():
                    continue
                try:
                    detect_reader(path)
                except EvsmapError:
                    continue
                return path
        return None

    def weights_path(self, spec: str, dataset: str) -> Path | None:
        """The weights file of ``spec`` on ``dataset`` (see :meth:`weights_choice`)."""
        choice = self.weights_choice(spec, dataset)
        return None if choice is None else choice.path

    def weights_choice(self, spec: str, dataset: str) -> WeightsChoice | None:
        """The weights file of segmenter ``spec`` (``name`` or ``name(k=v,...)``) for a cell on
        ``dataset``, and how it was found, in this order:

        1. ``<spec>@<dataset>.pt`` (or ``.pth``) in the weights folder;
        2. a file anywhere under the folder (``*.pt`` / ``*.pth``) whose card is for the same
           model, the same options as the factory takes them (defaults filled in, so a card
           with ``options = {}`` matches the bare name; ``num_classes`` compared with the
           card's classes) and ``dataset``. Several: the best ``val_miou``, then the newest
           (the card's ``created``, else the file's time), then weights files before training
           checkpoints, then the path;
        3. ``<name>@<dataset>.pt`` (or ``.pth``), the name without options.
        """
        if not self.weights_dir:
            return None
        folder = Path(self.weights_dir)
        name = re.sub(r"\(.*\)$", "", spec)
        for ext in (".pt", ".pth"):
            if (folder / f"{spec}@{dataset}{ext}").is_file():
                return self._by_name(folder / f"{spec}@{dataset}{ext}", spec, dataset)
        model, options = parse_spec(spec)
        matches = [e for e in self.weights_index() if e.get("card") is not None
                   and card_mismatch(e["card"], model, options, dataset) is None]
        if matches:
            matches.sort(key=_rank)
            return WeightsChoice(path=folder / matches[0]["file"], file=matches[0]["file"],
                                 found_by="card", card=matches[0]["card"],
                                 candidates=tuple(e["file"] for e in matches))
        for ext in (".pt", ".pth"):
            if (folder / f"{name}@{dataset}{ext}").is_file():
                return self._by_name(folder / f"{name}@{dataset}{ext}", spec, dataset)
        return None

    def _by_name(self, path: Path, spec: str, dataset: str) -> WeightsChoice:
        rel = path.name
        entry = next((e for e in self.weights_index() if e["file"] == rel), None)
        card = entry.get("card") if entry else None
        mismatch = None
        if card is not None:
            model, options = parse_spec(spec)
            mismatch = card_mismatch(card, model, options, dataset)
        return WeightsChoice(path=path, file=rel, found_by="name", card=card, mismatch=mismatch)

    def weights_index(self) -> list[dict[str, Any]]:
        """The cards of every ``*.pt`` / ``*.pth`` file under the weights folder, read once per
        run: kept on the context, and in ``<out>/cache/weights-cards.json`` for the cells' own
        processes (an entry is read again only when its file's size or time changed). Each
        entry: ``file`` (relative to the folder), ``size``, ``mtime_ns``, ``checkpoint``,
        ``error`` and ``card`` (:func:`card_summary`, None without a card)."""
        if not self.weights_dir:
            return []
        cached: tuple[str, list[dict[str, Any]]] | None = getattr(self, "_weights_index", None)
        if cached is not None and cached[0] == self.weights_dir:
            return cached[1]
        out = Path(self.out)
        entries = index_weights(Path(self.weights_dir),
                                out / "cache" / WEIGHTS_INDEX if out.is_dir() else None)
        self._weights_index = (self.weights_dir, entries)
        return entries

    def available(self, requires: list[str] | tuple[str, ...]) -> list[str]:
        """The requirements among ``requires`` that are satisfied here."""
        have = []
        for req in requires:
            kind, _, what = req.partition(":")
            if kind == "dataset" and self.dataset_path(what) is not None:
                have.append(req)
            elif kind == "weights":
                spec, _, dataset = what.rpartition("@")
                if self.weights_path(spec, dataset) is not None:
                    have.append(req)
            # hardware (a Jetson with TensorRT) is never available to this harness
        return have


# ----------------------------------------------------------------------------- weights by card
WEIGHTS_INDEX = "weights-cards.json"
"""The run's index of the weights folder's cards, under ``<out>/cache/``."""

_NOT_OPTIONS = ("weights", "backend", "input_size")
"""Segmenter options that say how weights are used, not which network they fit."""

_SUMMARY_KEYS = ("model", "options", "num_classes", "epochs", "created", "tensors_sha256")


@dataclass(frozen=True)
class WeightsChoice:
    """The weights file of a cell and how it was found.

    Attributes:
        path: the file.
        file: its path relative to the weights folder.
        found_by: ``name`` (``<spec>@<dataset>.pt`` or ``<name>@<dataset>.pt``) or ``card``.
        card: :func:`card_summary` of its card, None when it has none.
        candidates: found by card: every matching file, the chosen one first.
        mismatch: found by name: how its card disagrees with the cell, else None.
    """

    path: Path
    file: str
    found_by: str
    card: dict[str, Any] | None = None
    candidates: tuple[str, ...] = ()
    mismatch: str | None = None

    def note(self) -> str:
        """``weights: FILE (card: model, dataset, epochs, val mIoU, sha256 prefix)`` and how the
        file was chosen, for the record's notes."""
        from evsmap.segmenters.cards import format_options

        if self.card is None:
            text = f"weights: {self.file} (no card)"
        else:
            c = self.card
            opts = format_options(c.get("options"))
            parts = [f"{c.get('model') or '?'}" + (f"({opts})" if opts else ""),
                     str(c.get("dataset") or "dataset not on the card")]
            if isinstance(c.get("epochs"), int):
                parts.append(f"{c['epochs']} epochs")
            if isinstance(c.get("val_miou"), (int, float)):
                parts.append(f"val mIoU {100 * c['val_miou']:.1f} %")
            if isinstance(c.get("test_miou"), (int, float)) and c["test_miou"] != c.get(
                    "val_miou"):  # train validates on test where a dataset has no val split
                parts.append(f"test mIoU {100 * c['test_miou']:.1f} %")
            if isinstance(c.get("tensors_sha256"), str):
                parts.append(f"sha256 {c['tensors_sha256'][:8]}")
            text = f"weights: {self.file} (card: {', '.join(parts)})"
        if self.found_by == "card":
            text += "; found by its card"
            others = self.candidates[1:]
            if others:
                text += (f", the first of {len(self.candidates)} matching files by val mIoU, "
                         f"then the newest (also matching: {', '.join(others)})")
        elif self.mismatch:
            text += f"; named for this cell, but its card {self.mismatch}"
        return text


def parse_spec(spec: str) -> tuple[str, dict[str, Any]]:
    """``name(k=v,...)`` (:attr:`evsmap.tables.schema.Component.spec`) as ``(name, options)``;
    values read as ``-o KEY=VALUE`` reads them (true/false, int, float, else text)."""
    from evsmap.options import parse_key_value

    match = re.fullmatch(r"\s*([^()]+?)\s*(?:\((.*)\))?\s*", spec)
    if match is None:
        return spec, {}
    options = dict(parse_key_value(part) for part in (match.group(2) or "").split(",")
                   if part.strip())
    return match.group(1), options


def _factory_options(model: str, options: Mapping[str, Any]) -> tuple[dict[str, Any], Any]:
    """``(options, num_classes)`` as the segmenter's factory takes them: its defaults updated
    with ``options``, without the options that do not choose the network; ``num_classes``
    apart (None: the network's count follows from other options, e.g. ESANet's dataset)."""
    from evsmap.errors import EvsmapError
    from evsmap.registry import SEGMENTERS

    try:
        full: dict[str, Any] = SEGMENTERS.get(model).defaults()
    except EvsmapError:
        full = {}
    full.update(options)
    for key in _NOT_OPTIONS:
        full.pop(key, None)
    return full, full.pop("num_classes", None)


def card_mismatch(card: Mapping[str, Any], model: str, options: Mapping[str, Any],
                  dataset: str) -> str | None:
    """None when ``card`` (:func:`card_summary`) is for ``model`` with ``options`` on
    ``dataset``; else what differs, e.g. ``is for dataset sunrgbd``."""
    from evsmap.segmenters.cards import card_spec

    if card.get("model") != model:
        return f"is for {card_spec(card)}"
    if card.get("dataset") != dataset:
        return f"is for dataset {card.get('dataset') or '(not on the card)'}"
    raw = card.get("options")
    theirs, their_classes = _factory_options(model, raw if isinstance(raw, Mapping) else {})
    ours, our_classes = _factory_options(model, options)
    if isinstance(card.get("num_classes"), int):
        their_classes = card["num_classes"]
    if theirs != ours:
        return f"is for {card_spec(card)}"
    if None not in (our_classes, their_classes) and our_classes != their_classes:
        return f"has {their_classes} classes, not {our_classes}"
    return None


def card_summary(card: Mapping[str, Any]) -> dict[str, Any]:
    """What the runner keeps of a card: model, options, classes, dataset (as the runner names
    datasets), epochs, val/test mIoU, created, tensors_sha256 - as plain JSON data, so that an
    index read back from disk compares as one just read."""
    from evsmap.segmenters.cards import card_dataset, card_miou

    out = {k: card.get(k) for k in _SUMMARY_KEYS}
    out.update(dataset=card_dataset(card), val_miou=card_miou(card, "val"),
               test_miou=card_miou(card, "test"))
    plain: dict[str, Any] = json.loads(json.dumps(out, default=str))
    return plain


def _timestamp(entry: Mapping[str, Any]) -> float:
    created = (entry.get("card") or {}).get("created")
    if isinstance(created, str):
        try:
            return datetime.fromisoformat(created).timestamp()
        except ValueError:
            pass
    return float(entry.get("mtime_ns") or 0) / 1e9


def _rank(entry: Mapping[str, Any]) -> tuple[float, float, bool, str]:
    val = entry["card"].get("val_miou")
    val = val if isinstance(val, (int, float)) and math.isfinite(val) else -math.inf
    return (-val, -_timestamp(entry), bool(entry.get("checkpoint")), entry["file"])


def index_weights(folder: Path, cache: Path | None = None) -> list[dict[str, Any]]:
    """One entry per weights file under ``folder`` (see :meth:`RunContext.weights_index`),
    reusing ``cache`` entries whose file is unchanged and rewriting ``cache`` when needed."""
    from evsmap.segmenters.cards import find_weights_files, inspect_weights

    if not folder.is_dir():
        return []
    key = str(folder.resolve())
    known: dict[str, Any] = {}
    if cache is not None and cache.is_file():
        try:
            stored = json.loads(cache.read_text())
            if isinstance(stored, dict) and stored.get("folder") == key:
                known = stored.get("files") or {}
        except (OSError, ValueError):
            known = {}
    entries, changed = [], False
    for path in find_weights_files([folder]):
        rel = path.relative_to(folder).as_posix()
        try:
            stat = path.stat()
        except OSError:
            continue
        old = known.get(rel)
        if isinstance(old, dict) and old.get("size") == stat.st_size and \
                old.get("mtime_ns") == stat.st_mtime_ns:
            entries.append(old)
            continue
        info = inspect_weights(path)
        entries.append({"file": rel, "size": stat.st_size, "mtime_ns": stat.st_mtime_ns,
                        "checkpoint": info.checkpoint, "error": info.error,
                        "card": card_summary(info.card) if info.card is not None
                        and info.error is None else None})
        changed = True
    if cache is not None and (changed or len(entries) != len(known)):
        try:
            cache.parent.mkdir(parents=True, exist_ok=True)
            tmp = cache.with_name(f".{cache.name}.{os.getpid()}.tmp")
            tmp.write_text(json.dumps({"folder": key, "files": {e["file"]: e for e in entries}},
                                      indent=1))
            tmp.replace(cache)
        except OSError:  # a read-only run folder: the index is kept in memory only
            pass
    return entries
