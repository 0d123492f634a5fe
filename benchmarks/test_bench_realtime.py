"""Real time on this machine (issue 20): every ratio of the goal measured in one run.

``nox -s bench -- -k realtime`` (or the whole ``nox -s bench``) measures, each side of a ratio
alternating with the other within the same test so that both see the same machine:

* **int8 / fp32 network speed** per network (ONNX Runtime, the frame size the network is measured
  at, the same threads; int8 = static QDQ, every scheme (the record names the one ``auto``
  picks on this machine's instruction set), calibrated on 16 evenly spaced frames
  of the synthetic room), with the int8 top-1 agreement with fp32 on held-out frames (another
  room). The networks are seeded and untrained, their BatchNorm statistics re-estimated on the
  calibration frames (:func:`~evsmap.segmenters.quantize.reestimate_batchnorm`: with the
  initial statistics every pixel gets the same class and agreement is a meaningless 100 %);
  agreement is then a floor, not a trained network's figure;
* **pipelined / sequential end to end**: ``evsmap map``'s loop (:func:`map_sequence`) with
  EVSMap (``multiclass-bayes``, 5 cm, max range 5 m) and FEAGNet-V1/V2 int8 on the synthetic
  room (60 frames, read as ``evsmap map`` reads it: rendered once into the cache) and on the
  real TUM fr1_xyz frames: frames / wall time, reading included;
* **the faithful path and the variants** (issue 40): the same pipelined loop with each
  ``postprocess`` (``network``: the faithful path; ``fused``: the same labels and EVSMap map;
  ``stride``: the named variant; accuracy costs in ``benchmarks/realtime_variants.py``);
* **multiclass-bayes / OctoMap C++ at 2 cm** on the TUM frames (the update alone, max range
  4 m, discretize on; the C++ side pays the same back-projection).

Each figure lands in the benchmark's ``extra_info`` (``--benchmark-autosave`` keeps it) and in
``reports/realtime/realtime.json``; a summary prints at the end (``-s`` shows it). Asserted: only
that each side ran; the goals are read from the figures (see the issue's closing note).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from evsmap.measure.int8 import spread
from evsmap.paths import REPO_ROOT

NETWORKS = ("feagnet-v1", "feagnet-v2", "esanet-r34-nbt1d", "fchardnet-70")
SCHEMES = ("u8s8", "u8s7", "u8u8", "s8s8")
CALIBRATION_FRAMES = 16
HELD_OUT = 6
RUNS = 15
OUT = REPO_ROOT / "reports" / "realtime"

_RESULTS: dict[str, dict] = {}


def _save(section: str, key: str, value: dict) -> None:
    _RESULTS.setdefault(section, {})[key] = value
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "realtime.json").write_text(json.dumps(_RESULTS, indent=2, default=float))


@pytest.fixture(scope="module")
def synthetic():
    from evsmap.registry import READERS

    return READERS.create("synthetic", render="cached")


@pytest.fixture(scope="module")
def held_out():
    from evsmap.synth.sequence import SyntheticSequence

    other = SyntheticSequence(scene="office", seed=1, frames=HELD_OUT)
    return [other.frame(i) for i in range(HELD_OUT)]


def _calibration(sequence):
    from evsmap.segmenters.quantize import evenly_spaced

    return [sequence.frame(i) for i in evenly_spaced(len(sequence), CALIBRATION_FRAMES)]


def _network(name: str, **options):
    import torch

    from evsmap.registry import SEGMENTERS

    torch.manual_seed(0)
    return SEGMENTERS.create(name, backend="onnxruntime", **options)


@pytest.mark.parametrize("name", NETWORKS)
def test_int8_over_fp32(benchmark, name, synthetic, held_out):
    from evsmap.measure.int8 import alternating_ms, int8_pair
    from evsmap.segmenters.quantize import top1_agreement

    fp32, int8 = int8_pair(lambda: _network(name), _calibration(synthetic), schemes=SCHEMES,
                           source="synthetic living_room s0")
    sides = {"fp32": fp32, **{f"int8-{s}": seg for s, seg in int8.items()}}
    times = alternating_ms(sides, held_out[0], RUNS)
    agreement = {scheme: top1_agreement(fp32, seg, held_out) for scheme, seg in int8.items()}
    inputs = fp32.preprocess(held_out[0])
    benchmark.group = "int8 / fp32 (network, onnxruntime)"
    from evsmap.environment import instruction_set
    from evsmap.segmenters.quantize import auto_scheme

    benchmark.pedantic(lambda: int8[auto_scheme()].logits(inputs), rounds=5, iterations=1,
                       warmup_rounds=1)
    record = {"input": list(fp32.input_size), **{k: spread(v) for k, v in times.items()},
              "instruction_set": instruction_set(), "auto_scheme": auto_scheme()}
    for scheme in SCHEMES:
        record[f"speedup_{scheme}"] = (record["fp32"]["ms_median"]
                                       / record[f"int8-{scheme}"]["ms_median"])
        record[f"agreement_{scheme}"] = agreement[scheme]
        record[f"fp32_nodes_{scheme}"] = len(int8[scheme].quantization.excluded)
    benchmark.extra_info.update(record)
    _save("int8", name, record)
    assert all(len(v) == RUNS for v in times.values())


def _tum():
    from evsmap.registry import READERS
    from evsmap.testing import require_sample

    return READERS.create("tum", path=str(require_sample("tum-fr1-xyz")),
                          max_time_difference=0.021)


@pytest.mark.parametrize("sequence_name", ["synthetic", "tum"])
@pytest.mark.parametrize("name", ["feagnet-v1", "feagnet-v2"])
def test_pipelined_over_sequential(benchmark, name, sequence_name, synthetic):
    from evsmap.measure.mapping import map_sequence
    from evsmap.registry import UPDATERS

    sequence = synthetic if sequence_name == "synthetic" else _tum()
    seg = _network(name)
    seg.calibrate(_calibration(sequence), source=sequence.name)
    records: dict[str, list] = {"pipelined": [], "sequential": []}

    def one(mode: str):
        rec = map_sequence(sequence, UPDATERS.create("multiclass-bayes", resolution=0.05,
                                                     max_range=5.0),
                           updater_name="multiclass-bayes", segmenter=seg, segmenter_name=name,
                           pipeline=mode == "pipelined")
        records[mode].append(rec)
        return rec

    for p in range(2):
        for mode in (("pipelined", "sequential") if p % 2 == 0 else ("sequential", "pipelined")):
            one(mode)
    benchmark.group = f"end to end {sequence_name}"
    benchmark.pedantic(lambda: one("pipelined"), rounds=1, iterations=1)
    summary = {}
    for mode, recs in records.items():
        hz = [r.wall_hz for r in recs]
        summary[mode] = {"wall_hz": float(np.median(hz)), "wall_hz_runs": hz,
                         "frames": recs[0].frames,
                         "stage_ms_median": recs[-1].stage_medians()}
    summary["ratio"] = summary["pipelined"]["wall_hz"] / summary["sequential"]["wall_hz"]
    summary["threads"] = records["pipelined"][-1].pipeline
    benchmark.extra_info.update(summary)
    _save("end_to_end", f"{name}/{sequence_name}/int8", summary)
    assert all(r.frames == len(sequence) for recs in records.values() for r in recs)


POSTPROCESSES = ("network", "fused", "stride")


@pytest.mark.parametrize("sequence_name", ["synthetic", "tum"])
@pytest.mark.parametrize("name", ["feagnet-v1", "feagnet-v2"])
def test_faithful_and_variants(benchmark, name, sequence_name, synthetic):
    """``evsmap map``'s pipelined loop, EVSMap, int8, with each ``postprocess``: the faithful
    ``network``, the exact ``fused`` and the ``stride`` variant, alternating (two runs each)."""
    from evsmap.measure.mapping import map_sequence
    from evsmap.registry import UPDATERS

    sequence = synthetic if sequence_name == "synthetic" else _tum()
    calibration = _calibration(sequence)
    segs = {}
    for post in POSTPROCESSES:
        segs[post] = _network(name, postprocess=post)
        segs[post].calibrate(calibration, source=sequence.name)
    records: dict[str, list] = {post: [] for post in POSTPROCESSES}

    def one(post: str):
        rec = map_sequence(sequence, UPDATERS.create("multiclass-bayes", resolution=0.05,
                                                     max_range=5.0),
                           updater_name="multiclass-bayes", segmenter=segs[post],
                           segmenter_name=name, pipeline=True)
        records[post].append(rec)
        return rec

    for p in range(2):
        for post in (POSTPROCESSES if p % 2 == 0 else POSTPROCESSES[::-1]):
            one(post)
    benchmark.group = f"postprocess {sequence_name}"
    benchmark.pedantic(lambda: one("fused"), rounds=1, iterations=1)
    summary: dict = {}
    for post, recs in records.items():
        hz = [r.wall_hz for r in recs]
        summary[post] = {"wall_hz": float(np.median(hz)), "wall_hz_runs": hz,
                         "frames": recs[0].frames, "stage_ms_median": recs[-1].stage_medians()}
    summary["instruction_set"] = segs["network"].precision_record()["instruction_set"]
    summary["int8_scheme"] = segs["network"].int8_scheme
    benchmark.extra_info.update(summary)
    _save("postprocess", f"{name}/{sequence_name}/int8", summary)
    assert all(r.frames == len(sequence) for recs in records.values() for r in recs)


def test_multiclass_bayes_over_octomap_2cm(benchmark):
    import torch

    from evsmap.mapping.raycast import frame_points
    from evsmap.registry import SEGMENTERS, UPDATERS
    from evsmap.testing import require_module

    octomap = require_module("octomap")
    sequence = _tum()
    frames = [sequence.frame(i) for i in range(len(sequence))]
    torch.manual_seed(0)
    seg = SEGMENTERS.create("feagnet-v1")
    observations = [seg.predict(f) for f in frames]
    times: dict[str, list[float]] = {"multiclass-bayes": [], "octomap-cpp": []}

    def mcb():
        # the direct front end: OctoMap's own rays (insertPointCloud, discretize, 4 m), so both
        # sides cast the same rays (SSMI's generator casts free space to 2 m only)
        m = UPDATERS.create("multiclass-bayes", resolution=0.02, max_range=4.0,
                            front_end="direct")
        for f, o in zip(frames, observations, strict=True):
            t0 = time.perf_counter()
            m.integrate(f, o)
            times["multiclass-bayes"].append((time.perf_counter() - t0) * 1e3)

    def cpp():
        tree = octomap.OcTree(0.02)
        for f in frames:
            t0 = time.perf_counter()
            points, origin = frame_points(f)
            tree.insertPointCloud(points, origin, 4.0, False, True)
            times["octomap-cpp"].append((time.perf_counter() - t0) * 1e3)

    for p in range(3):
        for run in ((mcb, cpp) if p % 2 == 0 else (cpp, mcb)):
            run()
    benchmark.group = "multiclass-bayes / octomap 2 cm"
    benchmark.pedantic(mcb, rounds=1, iterations=1)
    from evsmap.mapping.threads import threading_info

    record = {k: spread(v) for k, v in times.items()}
    record["ratio"] = record["octomap-cpp"]["ms_median"] / \
        record["multiclass-bayes"]["ms_median"]
    record["threads"] = threading_info()
    benchmark.extra_info.update(record)
    _save("update_2cm", "tum-fr1-xyz", record)
    assert times["multiclass-bayes"] and times["octomap-cpp"]


@pytest.fixture(scope="module", autouse=True)
def _summary():
    yield
    if not _RESULTS:
        return
    lines = ["", "real time (issue 20), this run:"]
    for name, r in _RESULTS.get("int8", {}).items():
        lines.append(f"  {name:18s} fp32 {r['fp32']['ms_median']:7.1f} ms  " + "  ".join(
            f"{s} {r[f'int8-{s}']['ms_median']:6.1f} ms (x{r[f'speedup_{s}']:.2f}, top-1 "
            f"agreement {100 * r[f'agreement_{s}']:.1f} %)" for s in SCHEMES))
    for key, r in _RESULTS.get("end_to_end", {}).items():
        lines.append(f"  {key:28s} pipelined {r['pipelined']['wall_hz']:5.1f} Hz, "
                     f"sequential {r['sequential']['wall_hz']:5.1f} Hz "
                     f"(x{r['ratio']:.2f})")
    for key, r in _RESULTS.get("postprocess", {}).items():
        lines.append(f"  {key:28s} " + ", ".join(
            f"{post} {r[post]['wall_hz']:5.1f} Hz" for post in POSTPROCESSES)
            + f" (pipelined, {r['instruction_set']}, int8 {r['int8_scheme']})")
    for key, r in _RESULTS.get("update_2cm", {}).items():
        lines.append(f"  multiclass-bayes / OctoMap C++ at 2 cm on {key}: x{r['ratio']:.2f} "
                     f"({r['multiclass-bayes']['ms_median']:.1f} vs "
                     f"{r['octomap-cpp']['ms_median']:.1f} ms)")
    print("\n".join(lines))
    Path(OUT / "summary.txt").write_text("\n".join(lines[1:]) + "\n")
