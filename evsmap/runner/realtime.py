"""``evsmap reproduce --precision int8`` with Table IV: EVSMap end to end on this machine, the
faithful path beside its named variants (issue 40).

For FEAGNet-V1 and V2 (int8, the scheme ``auto`` picks for the instruction set, calibrated on 16
evenly spaced frames of the room) one record each, ``extra/realtime/<network>@synthetic``:
``evsmap map``'s pipelined loop (:func:`~evsmap.measure.mapping.map_sequence`) with EVSMap
(``multiclass-bayes``) at the run's voxel size on the synthetic room, once with every
``postprocess`` (:data:`~evsmap.segmenters.network.POSTPROCESSES`: ``network`` the faithful
path, ``fused`` the same labels and map, ``stride`` the named variant), in alternating order
(two rounds, one with ``--quick``), so that the ratios are taken in one run. Values: each path's
``wall_hz`` (frames / wall time, reading included) median; details: every run's rate and stage
medians, the instruction set and the int8 scheme. The report prints them after Table IV
(:mod:`evsmap.report.realtime`). The networks keep their seeded weights unless the run found
trained ones: speed does not depend on them (the accuracy cost of the variant is measured with
trained weights by ``benchmarks/realtime_variants.py``, docs/realtime.md).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from evsmap.runner.cell_base import error_record, now
from evsmap.runner.records import CellRecord, RecordStore

if TYPE_CHECKING:
    from evsmap.runner.context import RunContext

PREFIX = "extra/realtime/"
NETWORKS = ("feagnet-v1", "feagnet-v2")
SEQUENCE = "synthetic"
UPDATER = "multiclass-bayes"
CALIBRATION_FRAMES = 16
INPUT_SIZE: tuple[int, int] | None = None
"""The networks' input size (None: the size the paper measures them at, 480x640)."""


def realtime_key(network: str, sequence: str = SEQUENCE) -> str:
    return f"{PREFIX}{network}@{sequence}"


def _segmenters(network: str, calibration: list[Any], source: str) -> dict[str, Any]:
    import torch

    from evsmap.registry import SEGMENTERS
    from evsmap.segmenters.network import POSTPROCESSES, NetworkSegmenter

    segs = {}
    for post in POSTPROCESSES:
        torch.manual_seed(0)
        seg = SEGMENTERS.create(network, backend="onnxruntime", postprocess=post,
                                input_size=INPUT_SIZE)
        assert isinstance(seg, NetworkSegmenter)  # a FEAGNet
        seg.calibrate(calibration, source=source)
        segs[post] = seg
    return segs


def realtime_record(ctx: RunContext, network: str) -> CellRecord:
    """The record of ``network`` (see the module docstring)."""
    from evsmap.measure.mapping import map_sequence
    from evsmap.registry import UPDATERS
    from evsmap.runner.mapping_plan import open_mapping_sequence
    from evsmap.segmenters.network import POSTPROCESSES
    from evsmap.segmenters.quantize import evenly_spaced

    started, t0 = now(), time.perf_counter()
    base: dict[str, Any] = dict(
        key=realtime_key(network), table="extra", row=f"realtime-{network}",
        label=f"EVSMap + {network} int8, end to end", kind="mapping", metrics=[],
        inputs={"segmenter": network, "updater": UPDATER, "sequence": SEQUENCE,
                "resolution": ctx.resolution}, started=started)
    try:
        sequence = open_mapping_sequence(ctx, SEQUENCE)
        frames = len(sequence) if ctx.frames is None else min(ctx.frames, len(sequence))
        calibration = [sequence.frame(i) for i in evenly_spaced(frames, CALIBRATION_FRAMES)]
        segs = _segmenters(network, calibration, f"{sequence.name}: {len(calibration)} frames")
        runs: dict[str, list[dict[str, Any]]] = {post: [] for post in POSTPROCESSES}
        for round_ in range(1 if ctx.quick else 2):
            for post in POSTPROCESSES if round_ % 2 == 0 else POSTPROCESSES[::-1]:
                rec = map_sequence(sequence, UPDATERS.create(UPDATER, resolution=ctx.resolution),
                                   updater_name=UPDATER, segmenter=segs[post],
                                   segmenter_name=network, frames=frames, pipeline=True)
                runs[post].append({"wall_hz": rec.wall_hz, "stage_ms": rec.stage_medians(),
                                   "pipeline": rec.pipeline})
        values = {f"wall_hz_{post}": _median([r["wall_hz"] for r in runs[post]])
                  for post in POSTPROCESSES}
        quant = segs["network"].precision_record()
        details = {"runs": runs, "instruction_set": quant.get("instruction_set"),
                   "int8_scheme": quant.get("int8_scheme"),
                   "int8_scheme_chosen_by": quant.get("int8_scheme_chosen_by"),
                   "frames": frames}
        notes = [f"{frames} frames of {sequence.name} at {ctx.resolution:g} m, pipelined, "
                 f"int8 {quant.get('int8_scheme')} on {quant.get('instruction_set')}; median "
                 f"of {len(runs['network'])} alternating runs per path"]
        return CellRecord(**base, status="ok", values=values, notes=notes, details=details,
                          seconds=time.perf_counter() - t0)
    except Exception as exc:  # one network's failure does not stop the other
        return error_record(base, exc, t0)


def _median(values: list[float]) -> float:
    import statistics

    return float(statistics.median(values))


def run_realtime(ctx: RunContext, *, resume: bool = False, force: bool = False,
                 say: Callable[[str], object] = print) -> list[CellRecord]:
    """One record per network of :data:`NETWORKS`, written to the run's record store; with
    ``resume``, records already there are kept."""
    store = RecordStore(ctx.out)
    say(f"real time: EVSMap end to end with {', '.join(NETWORKS)} int8, faithful path and "
        f"variants")
    records = []
    for network in NETWORKS:
        rec = store.get(realtime_key(network)) if resume and not force else None
        if rec is None:
            rec = realtime_record(ctx, network)
            store.write(rec)
        records.append(rec)
    return records
