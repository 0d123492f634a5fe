"""``evsmap reproduce --train``: proxy weights on evsmap's synthetic rooms (not the paper's data).

For each proxy network, the weights are looked up by card (model, dataset ``synthrooms``) in the
run's weights folder; missing ones are trained with ``evsmap train``'s loop and a recipe
(``synth-proxy``) into ``<weights folder>/proxy/<model>@synthrooms/``. Then:

* one accuracy record per network, ``extra/proxy/<model>/synthrooms``: the mIoU on the
  synthrooms ``test`` split, measured as the accuracy cells measure it (and as the card's
  ``test_miou`` was: torch, the segmenter's own input size, one confusion matrix);
* two mapping records with one trained network (FEAGNet-V2 if trained, else the first):
  Table IV's TFEAGMap (``classic-semantic``) and EVSMap (``multiclass-bayes``) updaters on the
  first synthrooms test room, each map scored against that room's ground-truth voxels
  (:func:`evsmap.metrics.evaluate_map`), ``extra/proxy-mapping/<row>/synthrooms-room<N>``.

These records never fill the paper's cells; the report prints them in their own "Synthetic proxy"
sections (Tables I, III and IV) and in ``extra.csv``.
"""

from __future__ import annotations

import math
import time
import traceback
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from evsmap.errors import EvsmapError
from evsmap.interrupt import reraise_interruption
from evsmap.paths import REPO_ROOT
from evsmap.runner.context import RunContext, WeightsChoice
from evsmap.runner.records import CellRecord, RecordStore
from evsmap.tables.schema import mapping_table_id

DATASET = "synthrooms"
PROXY_MODELS = ("feagnet-v1", "feagnet-v2", "fchardnet-70")
PROXY_RECIPE = "synth-proxy"
MAPPING_NETWORK = "feagnet-v2"
MAPPING_ROWS = ("tfeagmap", "evsmap")
"""Table IV's rows whose updaters map with the trained network (classic-semantic,
multiclass-bayes)."""
QUICK_ROOMS: dict[str, Any] = {"rooms": 8, "frames_per_room": 1, "size": (128, 192)}
QUICK_OVERRIDES = {"epochs": 1, "workers": 0, "batch_size": 4, "crop": [128, 192]}
SECTION = "Synthetic proxy (evsmap's synthrooms, not the paper's datasets)"


def default_weights_dir() -> Path:
    return Path.home() / ".cache" / "evsmap" / "weights"


def synthrooms_folder(ctx: RunContext, say: Callable[[str], None] = print) -> Path:
    """The prepared synthrooms dataset: with ``--quick`` a tiny one in the run's cache, else the
    one found under the data roots, else prepared with default options into
    ``datasets/synthrooms``."""
    from evsmap.datasets.common import read_manifest
    from evsmap.datasets.synthrooms import prepare_synthrooms

    if ctx.quick:
        folder = Path(ctx.out) / "cache" / "synthrooms"
        if not (folder.is_dir() and read_manifest(folder) is not None):
            say(f"preparing a tiny synthrooms ({QUICK_ROOMS['rooms']} rooms x "
                f"{QUICK_ROOMS['frames_per_room']} frames, --quick) in {folder}")
            prepare_synthrooms(folder, overwrite=True, **QUICK_ROOMS)
        return folder
    found = ctx.dataset_path(DATASET)
    if found is not None:
        return found
    folder = REPO_ROOT / "datasets" / DATASET
    say(f"preparing synthrooms with default options in {folder} (no prepared one found)")
    prepare_synthrooms(folder)  # an error where a folder of that name holds something else
    return folder


def _weights_dir(ctx: RunContext) -> Path:
    """The run's weights folder (``--train`` always has one)."""
    if ctx.weights_dir is None:
        raise EvsmapError("reproduce --train needs a weights folder (--weights DIR)")
    return Path(ctx.weights_dir)


def _forget_index(ctx: RunContext) -> None:
    ctx.__dict__.pop("_weights_index", None)


def proxy_choice(ctx: RunContext, model: str) -> WeightsChoice | None:
    """The weights of ``model`` on synthrooms by card; among equally ranked files of a run, the
    one whose card has the final test pass (``best.pt``)."""
    from dataclasses import replace

    choice = ctx.weights_choice(model, DATASET)
    if choice is None or choice.found_by != "card" or (choice.card or {}).get(
            "test_miou") is not None:
        return choice
    cards = {e["file"]: e.get("card") for e in ctx.weights_index()}
    for file in choice.candidates:
        card = cards.get(file) or {}
        if card.get("test_miou") is not None and card.get("val_miou") == (choice.card or {}).get(
                "val_miou"):
            return replace(choice, path=_weights_dir(ctx) / file, file=file, card=card)
    return choice


def train_missing(ctx: RunContext, models: list[str], recipe: str, data: Path,
                  say: Callable[[str], None] = print) -> dict[str, str]:
    """Train every model of ``models`` without synthrooms weights in the weights folder; returns
    model -> error message for those whose training failed."""
    from evsmap.train.loop import train
    from evsmap.train.options import RunOptions
    from evsmap.train.recipe import apply_overrides, load_recipe

    failed = {}
    overrides = dict(QUICK_OVERRIDES) if ctx.quick else {}
    for model in models:
        if proxy_choice(ctx, model) is not None:
            continue
        folder = _weights_dir(ctx) / "proxy" / f"{model}@{DATASET}"
        epochs = apply_overrides(load_recipe(recipe), overrides).epochs
        resume = (folder / "checkpoint.pt").is_file()
        say(f"training proxy weights: {model} on {DATASET}, recipe {recipe}, {epochs} epochs, "
            f"into {folder}" + (" (resuming its checkpoint)" if resume else "")
            + " - this takes long")
        try:
            train(RunOptions(model=model, dataset=str(data), out=folder, recipe=recipe,
                             overrides=overrides, resume=resume))
        except Exception as exc:  # the run goes on; the model's records say it has no weights
            reraise_interruption(exc)
            text = str(exc) if isinstance(exc, EvsmapError) else f"{type(exc).__name__}: {exc}"
            failed[model] = text
            say(f"  training {model} failed: {text}")
        _forget_index(ctx)
    return failed


def _record(key: str, row: str, label: str, kind: str, **kw: Any) -> CellRecord:
    return CellRecord(key=key, table="extra", row=row, label=label, kind=kind,
                      metrics=["miou"] if kind == "accuracy" else [], **kw)


def accuracy_key(model: str) -> str:
    return f"extra/proxy/{model}/{DATASET}"


def mapping_key(row: str, room: int) -> str:
    return f"extra/proxy-mapping/{row}/{DATASET}-room{room}"


def proxy_accuracy(ctx: RunContext, model: str, data: Path) -> CellRecord:
    """The mIoU of ``model``'s proxy weights on the synthrooms test split."""
    from evsmap.runner.network_cells import dataset_miou
    from evsmap.segmenters.cards import inspect_weights
    from evsmap.tables.schema import Component

    key, label = accuracy_key(model), f"{model} (synthrooms proxy)"
    inputs = {"segmenter": model, "datasets": [DATASET], "split": "test", "sequence": DATASET}
    choice = proxy_choice(ctx, model)
    if choice is None:
        need = f"weights:{model}@{DATASET}"
        return _record(key, model, label, "accuracy", status="na", needs=[need],
                       reason=f"n/a - no {DATASET} weights of {model} (training failed)",
                       inputs=inputs)
    result, frames = dataset_miou(Component(model), DATASET, data, "test", choice.path,
                                  backend="torch")
    card = inspect_weights(choice.path).card or {}
    details = {"weights": choice.file, "recipe": card.get("recipe_name"),
               "epochs": card.get("epochs"), "val_miou": card.get("val_miou"),
               "card_test_miou": card.get("test_miou"), "frames": frames,
               "confusion": result.as_dict()}
    values = {"miou": float(result.miou)} if math.isfinite(result.miou) else {}
    notes = [f"{DATASET} test split ({data}), {frames} images, torch at the segmenter's input "
             f"size (as the card's test_miou)", choice.note()]
    return _record(key, model, label, "accuracy", status="ok", values=values, notes=notes,
                   details=details, inputs={**inputs, "weights": choice.file})


def proxy_mapping(ctx: RunContext, model: str, data: Path) -> list[CellRecord]:
    """Table IV's TFEAGMap and EVSMap updaters on the first synthrooms test room, labels from
    ``model``'s proxy weights, each map scored against the room's ground truth."""
    from evsmap.datasets.common import read_manifest
    from evsmap.metrics import evaluate_map
    from evsmap.registry import READERS, UPDATERS
    from evsmap.runner.network_cells import build_segmenter
    from evsmap.synth.sequence import SyntheticSequence
    from evsmap.tables.schema import Component, mapping_table

    manifest = read_manifest(data) or {}
    room = int(manifest["split_rooms"]["test"][0])
    info = next(r for r in manifest["rooms"] if int(r["index"]) == room)
    systems = {r.id: r for r in mapping_table().rows}
    choice = proxy_choice(ctx, model)
    sequence_name = f"{DATASET}-room{room}"
    records = []
    if choice is None:
        return [_record(mapping_key(row, room), row, f"{systems[row].label} + proxy {model}",
                        "mapping", status="na", needs=[f"weights:{model}@{DATASET}"],
                        reason=f"n/a - no {DATASET} weights of {model} (training failed)",
                        inputs={"sequence": sequence_name, "resolution": ctx.resolution})
                for row in MAPPING_ROWS]
    sequence = READERS.create(DATASET, path=str(data), room=room)
    n = len(sequence) if ctx.frames is None else min(ctx.frames, len(sequence))
    net = build_segmenter(Component(model), backend="torch", weights=str(choice.path))
    frames, observations, segment_ms = _segmented(sequence, n, net)
    truth = SyntheticSequence(scene=info["scene"], seed=int(info["seed"])).ground_truth(
        ctx.resolution)
    for row in MAPPING_ROWS:
        system = systems[row]
        component = system.updater
        if component is None:
            raise EvsmapError(f"the mapping table's row {row} has no updater")
        updater = UPDATERS.create(component.name, resolution=ctx.resolution,
                                  **component.config)
        update_ms = []
        for frame, obs in zip(frames, observations, strict=True):
            t0 = time.perf_counter()
            updater.integrate(frame, obs)
            update_ms.append((time.perf_counter() - t0) * 1000.0)
        quality = evaluate_map(updater, truth).as_dict()
        values = {"frames": float(n), "update_hz": float(1000.0 / np.median(update_ms))}
        for name in ("semantic_accuracy", "map_miou", "precision", "recall"):
            if quality.get(name) is not None and np.isfinite(quality[name]):
                values[name] = float(quality[name])
        records.append(_record(
            mapping_key(row, room), row, f"{system.label} + proxy {model}", "mapping",
            status="ok", values=values,
            notes=[f"{n} frames of {DATASET} test room {room} ({info['scene']}, layout seed "
                   f"{info['seed']}) at {ctx.resolution:g} m, labels from {model} (torch) with "
                   f"proxy weights {choice.file}; map scored against the room's ground-truth "
                   f"voxels", choice.note()],
            details={"quality": quality, "update_ms": update_ms, "segment_ms": segment_ms,
                     "room": room, "scene": info["scene"], "seed": info["seed"]},
            inputs={"segmenter": model, "updater": component.spec,
                    "sequence": sequence_name, "resolution": ctx.resolution,
                    "weights": choice.file}))
    return records


def _accuracy(ctx: RunContext, model: str, data: Path) -> list[CellRecord]:
    return [proxy_accuracy(ctx, model, data)]


def _segmented(sequence: Any, n: int, net: Any) -> tuple[list[Any], list[Any], list[float]]:
    """The first ``n`` frames of ``sequence``, ``net``'s prediction of each, and its time in
    milliseconds."""
    frames, observations, segment_ms = [], [], []
    for i in range(n):
        frame = sequence.frame(i)
        t0 = time.perf_counter()
        observations.append(net.predict(frame))
        segment_ms.append((time.perf_counter() - t0) * 1000.0)
        frames.append(frame)
    return frames, observations, segment_ms


def _guarded(make: Callable[[], list[CellRecord]], keys: list[tuple[str, str, str, str]],
             ctx: RunContext) -> list[CellRecord]:
    """``make()``, or one ``error`` record per (key, row, label, kind) when it raises."""
    from evsmap.runner.cell_base import environment
    from evsmap.runner.cell_base import now as _now

    started, t0 = _now(), time.perf_counter()
    try:
        records = make()
    except Exception as exc:  # recorded, the run goes on
        reraise_interruption(exc)
        text = str(exc) if isinstance(exc, EvsmapError) else f"{type(exc).__name__}: {exc}"
        records = [_record(key, row, label, kind, status="error", error=text,
                           details={"traceback": traceback.format_exc()})
                   for key, row, label, kind in keys]
    env = environment(ctx.threads)
    for rec in records:
        rec.started, rec.seconds, rec.environment = started, time.perf_counter() - t0, env
    return records


def run_proxy(ctx: RunContext, models: list[str], recipe: str, *, tables: list[str],
              resume: bool = False, force: bool = False,
              say: Callable[[str], None] = print) -> list[CellRecord]:
    """Train the missing proxy weights and record their accuracy (and, with Table IV, the two
    proxy maps); records already ``ok`` are kept when resuming."""
    store = RecordStore(ctx.out)
    data = synthrooms_folder(ctx, say)
    train_missing(ctx, models, recipe, data, say)
    out: list[CellRecord] = []

    def done(key: str) -> CellRecord | None:
        rec = store.get(key) if resume and not force else None
        return rec if rec is not None and rec.status == "ok" else None

    for model in models:
        rec = done(accuracy_key(model))
        if rec is None:
            rec = _guarded(partial(_accuracy, ctx, model, data),
                           [(accuracy_key(model), model, f"{model} (synthrooms proxy)",
                             "accuracy")], ctx)[0]
            store.write(rec)
        out.append(rec)
    if mapping_table_id() in tables and models:
        from evsmap.datasets.common import read_manifest

        net = MAPPING_NETWORK if MAPPING_NETWORK in models else models[0]
        room = int((read_manifest(data) or {})["split_rooms"]["test"][0])
        keys = [mapping_key(row, room) for row in MAPPING_ROWS]
        kept = [done(k) for k in keys]
        if all(kept):
            out += [k for k in kept if k is not None]
        else:
            recs = _guarded(lambda: proxy_mapping(ctx, net, data),
                            [(k, row, f"{row} + proxy {net}", "mapping")
                             for k, row in zip(keys, MAPPING_ROWS, strict=True)], ctx)
            for rec in recs:
                store.write(rec)
            out += recs
    return out
