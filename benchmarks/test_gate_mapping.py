"""Performance gate: the mapping goals of EVSMaP's multi-class Bayesian updater (Table IV).

On the 37 real TUM fr1_xyz frames (max range 4 m, discretize on, untrained seeded FEAGNet-V1
top-3 labels computed beforehand), at 5 cm and at 2 cm, asserted:

* update rate(multiclass-bayes -o front_end=direct) / update rate(octomap-cpp) >= 1 (the C++
  OctoMap, occupancy only, in the same run); the stretch goal 3 is reported (issue 20's 5 at 2 cm:
  ``benchmarks/test_bench_realtime.py``)
* the compiled and the numpy reference update write the same map (multiclass-bayes and
  classic-semantic, both with -o front_end=direct)

Reported, not asserted (the paper's claims that the paper's update as defined does not meet
here, see docs/mapping.md "Measured"):

* update rate(multiclass-bayes) / update rate(classic-semantic -o front_end=direct) > 1,
  compiled against compiled: like for like, both cast every ray to the max range and fuse with
  a numba kernel, so the update rules are compared, not numpy against numba; they cost about
  the same (18.1 against 18.2 ms a frame at 5 cm, loaded machine), so the ratio sits at 1

Against classic-semantic as semantic_slam runs it, both on the octomap_generator front end
(multiclass-bayes's default, SSMI's generator):

* update rate(multiclass-bayes) / rate(semantic_slam): semantic_slam casts free space only to
  2 m, far less work than a ray to 4 m, and its node pool walk is compiled too

* map file(classic-semantic) / map file(multiclass-bayes) >= 2 ("our EVSMap stores maps in the
  smallest memory"), each the file the system itself writes (semantic_slam: a ColorOcTree,
  8 B a node; EVSMap: its top-3 + others node, 24 B): with eq. 5's occupancy, free space
  saturates after 21 misses of phi = -0.1 instead of OctoMap's 5, so far fewer nodes prune
* update rate(multiclass-bayes direct with its numpy reference update) / rate(classic-semantic
  direct with its numpy reference update) > 1: numpy against numpy (``kernels="reference"``:
  the rays and points in numpy too)

Each pass maps the whole sequence into a fresh map with every updater, the updaters in
alternating order from pass to pass; a rate is 1000 / the median ms per frame over all passes.
Only ratios measured in this run are compared. Runs only with ``--benchmark-only``.
"""

from __future__ import annotations

import numpy as np
import pytest

import baselines.classic_semantic as cs
import evsmap.updaters.multiclass_bayes as mb
from evsmap.measure.engine import in_memory, run_mapping
from evsmap.measure.evaluators import MapFiles
from evsmap.registry import SEGMENTERS, UPDATERS

NAMES = ("octomap-cpp", "classic-semantic", "classic-semantic/direct",
         "classic-semantic/direct-numpy", "multiclass-bayes", "multiclass-bayes/direct",
         "multiclass-bayes/direct-numpy")
VARIANTS = {"direct": {"front_end": "direct"}}
REFERENCE = {  # "<name>/direct-numpy": what "<name>" -o front_end=direct builds, in numpy
    "multiclass-bayes": mb.MultiClassBayesMap,
    "classic-semantic": lambda **options: cs.ClassicSemanticMap(fusion_rule="bayes", **options)}
RESOLUTIONS = (0.05, 0.02)
PASSES = 3
MAX_RANGE = 4.0


def _updater(registered: str, variant: str, resolution: float):
    """The updater of one name in ``NAMES``: a ``-numpy`` variant runs every loop of the
    update in numpy (``kernels="reference"``)."""
    if variant.endswith("numpy"):
        return REFERENCE[registered](resolution=resolution, max_range=MAX_RANGE,
                                     kernels="reference")
    return UPDATERS.create(registered, resolution=resolution, max_range=MAX_RANGE,
                           **VARIANTS.get(variant, {}))


def _measure(frames, observations) -> dict:
    sequence = in_memory(frames, "tum-fr1-xyz")
    out = {}
    for res in RESOLUTIONS:
        times: dict[str, list[float]] = {n: [] for n in NAMES}
        size: dict[str, int] = {}
        for p in range(PASSES):
            for name in NAMES if p % 2 == 0 else NAMES[::-1]:
                registered, _, variant = name.partition("/")
                mapped = run_mapping(  # the engine every rate of evsmap is timed with
                    sequence, lambda r=registered, v=variant, res=res: _updater(r, v, res),
                    observations=observations, measure_memory=False,
                    evaluators=[MapFiles(formats=("published",))])  # Table IV's map size
                times[name] += mapped.update_ms
                size[name] = mapped.results["files"].sizes["published"]
        out[res] = {n: {"update_hz": float(1000.0 / np.median(times[n])),
                        "ms_median": float(np.median(times[n])),
                        "ms_iqr": float(np.subtract(*np.percentile(times[n], [75, 25]))),
                        "map_bytes": int(size[n])} for n in NAMES}
    return out


@pytest.mark.gate
def test_multiclass_bayes_mapping_goals(benchmark, capsys, tum_frames):
    import torch

    torch.manual_seed(0)
    segmenter = SEGMENTERS.create("feagnet-v1")
    observations = [segmenter.predict(f) for f in tum_frames]
    benchmark.group = "gate"
    result = benchmark.pedantic(_measure, args=(tum_frames, observations), rounds=1,
                                warmup_rounds=0, iterations=1)
    lines = [f"mapping gate (TUM fr1_xyz, {len(tum_frames)} frames, max range {MAX_RANGE} m, "
             f"{PASSES} passes)"]
    failed = []
    for res, figures in result.items():
        for name, r in figures.items():
            lines.append(f"  {res * 100:g} cm {name:32s} {r['update_hz']:6.1f} Hz  "
                         f"{r['ms_median']:6.1f} ms median (IQR {r['ms_iqr']:5.1f})  "
                         f"published file {r['map_bytes'] / 1e3:8.1f} KB")
        mcb, ref, slam, cls, mcb_np, cls_np, gen = (figures[n] for n in (
            "multiclass-bayes/direct", "octomap-cpp", "classic-semantic",
            "classic-semantic/direct", "multiclass-bayes/direct-numpy",
            "classic-semantic/direct-numpy", "multiclass-bayes"))
        hz = {key: figures[n]["update_hz"] for key, n in zip(
            ("mcb", "ref", "slam", "cls", "mcb_np", "cls_np", "gen"),
            ("multiclass-bayes/direct", "octomap-cpp", "classic-semantic",
             "classic-semantic/direct", "multiclass-bayes/direct-numpy",
             "classic-semantic/direct-numpy", "multiclass-bayes"), strict=True)}
        checks = {
            "rate vs octomap-cpp >= 1": hz["mcb"] / hz["ref"] >= 1.0,
            "same map with either update": mcb_np["map_bytes"] == mcb["map_bytes"],
            "same direct classic map with either update": cls_np["map_bytes"] == cls["map_bytes"],
        }
        claims = {
            # the paper's comparison: both on the octomap_generator front end
            "file semantic_slam / multiclass >= 2": slam["map_bytes"] / gen["map_bytes"] >= 2.0,
            "rate vs semantic_slam > 1": hz["gen"] / hz["slam"] > 1.0,
            # like for like, both compiled, the same rays (to max range): the update rules
            # cost about the same (docs/mapping.md), so this is reported, not asserted
            "rate vs classic-semantic direct > 1": hz["mcb"] / hz["cls"] > 1.0,
            "numpy rate vs classic-semantic direct numpy > 1": hz["mcb_np"] / hz["cls_np"] > 1.0,
        }
        lines.append(f"  {res * 100:g} cm paper claims (reported): " + ", ".join(
            f"{k}: {'met' if ok else 'NOT met'}" for k, ok in claims.items()))
        lines.append(f"  {res * 100:g} cm ratios: rate/octomap-cpp {hz['mcb'] / hz['ref']:.2f} "
                     f"(stretch goal 3: {'met' if hz['mcb'] >= 3 * hz['ref'] else 'not met'}), "
                     f"rate/direct classic {hz['mcb'] / hz['cls']:.2f}, generator rate/"
                     f"semantic_slam {hz['gen'] / hz['slam']:.2f}, file semantic_slam/multiclass "
                     f"(generator) {slam['map_bytes'] / gen['map_bytes']:.2f}, file direct "
                     f"classic/multiclass {cls['map_bytes'] / mcb['map_bytes']:.2f}, numpy update "
                     f"/ direct classic numpy {hz['mcb_np'] / hz['cls_np']:.2f}")
        failed += [f"{res * 100:g} cm: {k}" for k, ok in checks.items() if not ok]
    benchmark.extra_info.update(figures={str(k): v for k, v in result.items()})
    report = "\n".join(lines)
    with capsys.disabled():
        print("\n" + report)
    assert not failed, "mapping goals not met: " + "; ".join(failed) + "\n" + report
