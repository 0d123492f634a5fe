"""Which "Map Size" did the paper measure? Table IV's systems on the same frames and observations,
the map's size under each reading, the row ratios the paper prints for Seq.1 beside them, and the
map's growth with the frames.

    python benchmarks/table4_sizes.py [--sequence tum|synthetic|synthetic-long]
        [--resolution 0.02 0.05] [--frames N] [--json FILE]

Readings: the file each system itself saves (a ColorOcTree for all three: SSMI's node turns its
semantics off before saving), the full map as each ROS node sends it (``octomap_full``: SSMI's
``writeData`` with its semantics, 36 B a node; the saved file for the others), the colour-only
ColorOcTree every system can write, and OctoMap's memory model over each system's C++ node. Labels:
on ``tum`` (the real fr1_xyz sample) the seeded untrained FEAGNet-V1's, on the synthetic sequences
the oracle's (profile `per-pixel`, as docs/mapping.md measured them), one set for every system,
so TESAMap = TFEAGMap and MESAMap = EVSMap here (the paper's pairs differ only by the network).
Also: the same two updaters on the direct front end, nodes, pruned share, 3D accuracy and mIoU
where there is ground truth, update time.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import numpy as np

from evsmap.measure.engine import in_memory, run_mapping
from evsmap.measure.evaluators import MapFiles, MapStatistics, pruned_share
from evsmap.measure.growth import MapGrowth, growth_every
from evsmap.registry import READERS, SEGMENTERS, UPDATERS

SYSTEMS = {
    "ORGBMap (orgb)": ("orgb", {}),
    "TESAMap/TFEAGMap (classic-semantic)": ("classic-semantic", {}),
    "MESAMap/EVSMap (multiclass-bayes)": ("multiclass-bayes", {}),
    "classic-semantic -o front_end=direct": ("classic-semantic", {"front_end": "direct"}),
    "multiclass-bayes -o front_end=direct": ("multiclass-bayes", {"front_end": "direct"}),
}
READINGS = {"saved file": "published", "octomap_full message": "message",
            "colour-only file": "colour", "C++ memory": "memory"}
PAPER_SEQ1 = {"TESAMap / ORGBMap": 5.43 / 3.54, "MESAMap / TESAMap": 5.89 / 5.43,
              "EVSMap / TFEAGMap": 5.30 / 5.71}
PAIRS = {"TESAMap / ORGBMap": ("TESAMap/TFEAGMap (classic-semantic)", "ORGBMap (orgb)"),
         "MESAMap / TESAMap": ("MESAMap/EVSMap (multiclass-bayes)",
                               "TESAMap/TFEAGMap (classic-semantic)"),
         "EVSMap / TFEAGMap": ("MESAMap/EVSMap (multiclass-bayes)",
                               "TESAMap/TFEAGMap (classic-semantic)")}


def frames_and_labels(name: str, frames: int | None):
    if name == "tum":
        import torch

        from evsmap.testing import require_sample

        seq = READERS.create("tum", path=str(require_sample("tum-fr1-xyz")),
                             max_time_difference=0.021)
        torch.manual_seed(0)
        segmenter = SEGMENTERS.create("feagnet-v1")
    else:
        options = ({"frames": 60} if name == "synthetic" else
                   {"frames": 640, "laps": 4})
        seq = READERS.create("synthetic", noise=True, **options)
        segmenter = SEGMENTERS.create("oracle", profile="per-pixel", seed=0)  # as documented
    n = len(seq) if frames is None else min(frames, len(seq))
    picked = [seq.frame(i) for i in range(n)]
    return seq, picked, [segmenter.predict(f) for f in picked]


def measure(seq, frames, observations, resolution: float) -> list[dict]:
    truth = seq.ground_truth(resolution) if hasattr(seq, "ground_truth") else None
    rows = []
    for label, (name, options) in SYSTEMS.items():
        t0 = time.perf_counter()
        mapped = run_mapping(
            in_memory(frames, seq.name),
            lambda n=name, o=options: UPDATERS.create(n, resolution=resolution, **o),
            observations=observations, measure_memory=False,
            evaluators=[MapStatistics(), MapFiles(formats=("published", "colour", "message"))],
            growth=MapGrowth(every=growth_every(len(frames))))
        m = mapped.updater
        stats, sizes = mapped.results["stats"], mapped.results["files"].sizes
        row = {"system": label, "sequence": seq.name, "resolution": resolution,
               "frames": len(frames), "front_end": m.front_end, "nodes": stats.nodes,
               "leaves": stats.leaves, "pruned_share": pruned_share(m),
               "published": sizes["published"], "colour": sizes.get("colour"),
               "message": sizes.get("message", sizes["published"]),
               "memory": stats.octomap_memory_bytes,
               "update_ms_median": float(np.median(mapped.update_ms)),
               "growth": mapped.results["growth"], "wall_s": time.perf_counter() - t0}
        if truth is not None and m.uses_semantics:
            from evsmap.metrics import evaluate_map

            q = evaluate_map(m, truth)
            row.update(semantic_accuracy=q.semantic_accuracy,
                       semantic_accuracy_all=q.semantic_accuracy_all, map_miou=q.map_miou)
        rows.append(row)
        acc = (f" acc {100 * row['semantic_accuracy']:5.1f} % mIoU {100 * row['map_miou']:5.1f} %"
               if "semantic_accuracy" in row else "")
        print(f"{resolution * 100:g} cm {label:<40} nodes {row['nodes']:>9,} pruned "
              f"{100 * (row['pruned_share'] or 0):5.1f} %  saved "
              f"{row['published'] / 1e3:9.1f} KB  message {row['message'] / 1e3:9.1f} KB  "
              f"colour {(row['colour'] or 0) / 1e3:9.1f} KB  "
              f"memory {row['memory'] / 1e6:7.2f} MB  {row['update_ms_median']:7.1f} ms{acc}",
              flush=True)
    return rows


def consistency(rows: list[dict]) -> list[str]:
    """Per reading: the paper's Seq.1 row ratios measured, and how far they are from the
    paper's (mean absolute log ratio)."""
    by = {r["system"]: r for r in rows}
    lines = []
    for reading, key in READINGS.items():
        cells, errors = [], []
        for pair, (a, b) in PAIRS.items():
            ratio = by[a][key] / by[b][key]
            cells.append(f"{pair} {ratio:.2f} (paper {PAPER_SEQ1[pair]:.2f})")
            errors.append(abs(math.log(ratio / PAPER_SEQ1[pair])))
        lines.append(f"  {reading:<17} " + "; ".join(cells)
                     + f"; mean |log(measured/paper)| {np.mean(errors):.3f}")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sequence", choices=("tum", "synthetic", "synthetic-long"),
                    default="tum")
    ap.add_argument("--resolution", type=float, nargs="+", default=[0.02, 0.05])
    ap.add_argument("--frames", type=int)
    ap.add_argument("--json")
    args = ap.parse_args()
    seq, frames, observations = frames_and_labels(args.sequence, args.frames)
    out = []
    for res in args.resolution:
        rows = measure(seq, frames, observations, res)
        print(f"{res * 100:g} cm, {seq.name}, {len(frames)} frames: the paper's Seq.1 ratios")
        print("\n".join(consistency(rows)), flush=True)
        out += rows
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)


if __name__ == "__main__":
    main()
