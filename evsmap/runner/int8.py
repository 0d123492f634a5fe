"""``evsmap reproduce --precision int8``: every network of the run measured in int8 beside fp32.

For each network with a speed cell in the planned tables (one record per network and input
size, ``extra/int8/<segmenter>@<WxH>``), in one process, on ONNX Runtime with the run's threads:

* **speed**: the network's forward pass, fp32 and int8 (static QDQ, the scheme ``auto`` picks
  for the machine's instruction set, :mod:`evsmap.segmenters.quantize`) alternating run by run
  on the same input, medians and the speed-up int8 / fp32. The int8 model is calibrated on 16
  evenly spaced frames of the synthetic room (the built-in target data; no dataset is needed
  for a speed figure);
* **top-1 agreement** of int8 with fp32 on held-out frames (another synthetic room): the share of
  pixels whose class does not change. Untrained (seeded) networks get BatchNorm statistics of the
  calibration frames first (with the initial ones every pixel has the same class and agreement
  is a meaningless 100 %); their agreement is a floor, not a trained network's figure;
* **mIoU fp32 and int8** wherever the run can score the network: its accuracy cells whose dataset
  and weights are here (int8 calibrated on 16 evenly spaced frames of the dataset's ``train``
  split, never the scored split), and proxy weights on synthrooms (``reproduce --train``).

These records fill no paper cell; the report prints them in an "int8 beside fp32" section after
Tables I-III and in ``extra.csv``. The paper's speed cells stay fp32 (the paper measures its
networks in TensorRT on a Jetson; precision is not stated).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

from evsmap.errors import EvsmapError
from evsmap.runner.cell_base import error_record, now
from evsmap.runner.context import RunContext
from evsmap.runner.network_cells import cell_network
from evsmap.runner.records import CellRecord, RecordStore
from evsmap.tables.plan import CellSpec

if TYPE_CHECKING:
    from evsmap.data import Frame
    from evsmap.synth.sequence import SyntheticSequence

SCHEME = "auto"
CALIBRATION_FRAMES = 16
HELD_OUT_FRAMES = 6


def int8_key(spec: CellSpec) -> str:
    size = f"@{spec.input_size[1]}x{spec.input_size[0]}" if spec.input_size else ""
    return f"extra/int8/{cell_network(spec).spec}{size}"


def network_specs(specs: list[CellSpec]) -> list[CellSpec]:
    """One speed cell per network and input size, in plan order."""
    seen: set[str] = set()
    out: list[CellSpec] = []
    for s in specs:
        if s.kind != "speed" or s.segmenter is None or not s.runnable:
            continue
        key = int8_key(s)
        if key not in seen:
            seen.add(key)
            out.append(s)
    return out


def _synthetic(ctx: RunContext, *, scene: str, seed: int, frames: int) -> SyntheticSequence:
    from evsmap.synth.sequence import SyntheticSequence

    size = ctx.synthetic.get("width", 640), ctx.synthetic.get("height", 480)
    return SyntheticSequence(scene=scene, seed=seed, frames=frames, width=size[0],
                             height=size[1])


def _pair(spec: CellSpec, calibration: Sequence[Frame], source: str,
          weights: str | None = None) -> tuple[Any, Any]:
    """fp32 and int8 (:data:`SCHEME`) segmenters of ``spec``'s network, the same weights."""
    from evsmap.measure.int8 import int8_pair
    from evsmap.runner.network_cells import build_segmenter

    network = cell_network(spec)
    fp32, int8 = int8_pair(
        lambda: build_segmenter(network, input_size=spec.input_size,
                                backend="onnxruntime", weights=weights),
        calibration, schemes=(SCHEME,), source=source, untrained=weights is None)
    return fp32, int8[SCHEME]


def _speed(fp32: Any, int8: Any, frame: Frame, runs: int) -> dict[str, Any]:
    from evsmap.measure.int8 import alternating_ms, spread

    ms = alternating_ms({"fp32": fp32, "int8": int8}, frame, runs)
    out: dict[str, Any] = {"runs": runs}
    for name, values in ms.items():
        s = spread(values)
        out[f"{name}_ms"], out[f"{name}_ms_iqr"] = s["ms_median"], s["ms_iqr"]
    return out


def _accuracy_specs(specs: list[CellSpec], speed: CellSpec) -> list[CellSpec]:
    return [s for s in specs if s.kind == "accuracy" and s.runnable and s.segmenter is not None
            and s.segmenter.spec == cell_network(speed).spec]


def _miou_pair(ctx: RunContext, spec: CellSpec) -> dict[str, Any]:
    """mIoU of the accuracy cell ``spec`` in fp32 and int8 (int8 calibrated on the dataset's
    train split)."""
    from evsmap.registry import READERS
    from evsmap.runner.network_cells import score_segmenter
    from evsmap.segmenters.quantize import evenly_spaced

    dataset = spec.datasets[0]
    network = cell_network(spec)
    path = ctx.dataset_path(dataset)
    choice = ctx.weights_choice(network.spec, dataset)
    if path is None or choice is None:  # _accuracy_specs keeps the runnable cells only
        raise EvsmapError(f"{spec.key}: dataset or weights missing")
    split = spec.split or "test"
    train = READERS.create(dataset, path=str(path), split="train")
    calibration = [train.frame(i) for i in evenly_spaced(len(train), CALIBRATION_FRAMES)]
    fp32, int8 = _pair(spec, calibration, f"{dataset} train", weights=str(choice.path))
    out: dict[str, Any] = {"dataset": dataset, "split": split, "weights": choice.file}
    for name, seg in (("fp32", fp32), ("int8", int8)):
        result, _ = score_segmenter(seg, dataset, path, split, input_size=spec.input_size,
                                    limit=10 if ctx.quick else None, what=network.spec)
        out[f"miou_{name}"] = float(result.miou)
    return out


def int8_record(ctx: RunContext, spec: CellSpec, specs: list[CellSpec]) -> CellRecord:
    """The int8 figures of ``spec``'s network (see the module docstring)."""
    from evsmap.segmenters.quantize import evenly_spaced, top1_agreement

    started, t0 = now(), time.perf_counter()
    base: dict[str, Any] = dict(
        key=int8_key(spec), table="extra", row=spec.row, label=spec.label, kind="speed",
        metrics=[], inputs={"segmenter": cell_network(spec).spec, "input_size": spec.input_size,
                            "table": spec.table, "scheme": SCHEME},
        started=started)
    try:
        room = _synthetic(ctx, scene="living_room", seed=0, frames=60)
        calibration = [room.frame(i) for i in evenly_spaced(len(room), CALIBRATION_FRAMES)]
        held = _synthetic(ctx, scene="office", seed=1, frames=HELD_OUT_FRAMES)
        held_out = [held.frame(i) for i in range(2 if ctx.quick else HELD_OUT_FRAMES)]
        fp32, int8 = _pair(spec, calibration, "synthetic living_room s0")
        values = _speed(fp32, int8, held_out[0], 3 if ctx.quick else ctx.speed_runs)
        values["speedup"] = values["fp32_ms"] / values["int8_ms"]
        values["agreement"] = top1_agreement(fp32, int8, held_out)
        details: dict[str, Any] = {"quantization": int8.precision_record(), "accuracy": []}
        for acc in _accuracy_specs(specs, spec):
            try:
                details["accuracy"].append(_miou_pair(ctx, acc))
            except EvsmapError as exc:
                details["accuracy"].append({"dataset": acc.datasets[0], "error": str(exc)})
        scored = [a for a in details["accuracy"] if "miou_int8" in a]
        if scored:
            values["miou_fp32"] = scored[0]["miou_fp32"]
            values["miou_int8"] = scored[0]["miou_int8"]
        h, w = fp32.input_size
        notes = [f"onnxruntime on the CPU ({ctx.threads} threads), {w}x{h}, median of "
                 f"{values['runs']} alternating runs; int8 {SCHEME} calibrated on "
                 f"{len(calibration)} synthetic frames; agreement on {len(held_out)} held-out "
                 f"synthetic frames" + ("" if scored else "; untrained weights: no mIoU")]
        return CellRecord(**base, status="ok", values=values, notes=notes, details=details,
                          seconds=time.perf_counter() - t0)
    except Exception as exc:  # one network's failure does not stop the others
        return error_record(base, exc, t0)


def run_int8(ctx: RunContext, specs: list[CellSpec], *, resume: bool = False,
             force: bool = False, say: Callable[[str], object] = print
             ) -> list[CellRecord]:
    """One int8 record per network of ``specs`` (the planned cells), written to the run's
    record store; with ``resume``, records already there are kept."""
    store = RecordStore(ctx.out)
    records: list[CellRecord] = []
    todo = network_specs(specs)
    if todo:
        say(f"int8 beside fp32: {len(todo)} networks (quantise, time, compare)")
    for spec in todo:
        rec = store.get(int8_key(spec)) if resume and not force else None
        if rec is None:
            rec = int8_record(ctx, spec, specs)
            store.write(rec)
        records.append(rec)
    return records
