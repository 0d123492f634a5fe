"""Table IV's map sizes and what stands behind them: every mapping system on the same frames and
observations, with the file it itself writes (``published``) and evsmap's resumable state
(``full``), nodes, leaves, pruned share, the memory of the original C++ node types and of
evsmap's arrays, the update time, and - on the synthetic room - the map's 3D semantic accuracy.

    python benchmarks/table4_sizes.py [--sequence synthetic|tum] [--resolution 0.05]
        [--frames 60] [--oracle-accuracy 0.85] [--json FILE]

On ``tum`` (the real fr1_xyz sample) the labels come from the seeded untrained FEAGNet-V1 (no
ground truth to score against); on ``synthetic`` from the oracle at the given accuracy.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from evsmap.measure.mapping import map_sizes, pruned_share
from evsmap.metrics import evaluate_map
from evsmap.registry import READERS, SEGMENTERS, UPDATERS

SYSTEMS = {
    "multiclass-bayes (EVSMap)": ("multiclass-bayes", {}),
    "classic-semantic (semantic_slam as it runs)": ("classic-semantic", {}),
    "classic-semantic front_end=direct": ("classic-semantic", {"front_end": "direct"}),
    "classic-semantic-max (semantic_slam as it runs)": ("classic-semantic-max", {}),
    "orgb (OctoMap ColorOcTree)": ("orgb", {}),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sequence", choices=("synthetic", "tum"), default="synthetic")
    ap.add_argument("--resolution", type=float, default=0.05)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--oracle-accuracy", type=float, default=0.85)
    ap.add_argument("--json")
    args = ap.parse_args()
    if args.sequence == "tum":
        import torch

        from evsmap.testing import require_sample

        seq = READERS.create("tum", path=str(require_sample("tum-fr1-xyz")),
                             max_time_difference=0.021)
        torch.manual_seed(0)
        segmenter = SEGMENTERS.create("feagnet-v1")
        truth = None
    else:
        seq = READERS.create("synthetic", frames=args.frames)
        segmenter = SEGMENTERS.create("oracle", accuracy=args.oracle_accuracy)
        truth = seq.ground_truth(args.resolution)
    frames = [seq.frame(i) for i in range(min(len(seq), args.frames))]
    observations = [segmenter.predict(f) for f in frames]
    rows = []
    for label, (name, options) in SYSTEMS.items():
        m = UPDATERS.create(name, resolution=args.resolution, **options)
        semantic = getattr(m, "uses_semantics", False)
        times = []
        for f, o in zip(frames, observations, strict=True):
            t0 = time.perf_counter()
            m.integrate(f, o if semantic else None)
            times.append((time.perf_counter() - t0) * 1000.0)
        stats = m.stats()
        sizes = map_sizes(m)
        row = {"sequence": args.sequence, "resolution": args.resolution, "frames": len(frames),
               "system": label, "published_bytes": sizes["published"],
               "full_bytes": sizes["full"], "nodes": stats.nodes, "leaves": stats.leaves,
               "pruned_share": pruned_share(m), "memory_cpp_bytes": stats.octomap_memory_bytes,
               "memory_nbytes": m.memory_nbytes(), "update_ms_median": float(np.median(times))}
        if truth is not None and semantic:
            q = evaluate_map(m, truth)
            row.update(semantic_accuracy=q.semantic_accuracy,
                       semantic_accuracy_all=q.semantic_accuracy_all, map_miou=q.map_miou,
                       unlabelled_share=q.unlabelled / max(q.matched, 1),
                       precision=q.precision, recall=q.recall)
        rows.append(row)
        acc = (f"  acc {100 * row['semantic_accuracy']:5.1f} % (no class = wrong: "
               f"{100 * row['semantic_accuracy_all']:5.1f} %)  mIoU {100 * row['map_miou']:5.1f} %"
               if "semantic_accuracy" in row else "")
        print(f"{label:<50} published {row['published_bytes'] / 1e3:9.1f} KB  full "
              f"{row['full_bytes'] / 1e3:9.1f} KB  nodes {row['nodes']:>8,}  leaves "
              f"{row['leaves']:>8,}  pruned {100 * (row['pruned_share'] or 0):4.1f} %  C++ "
              f"{row['memory_cpp_bytes'] / 1e6:6.2f} MB  arrays "
              f"{(row['memory_nbytes'] or 0) / 1e6:6.2f} MB  {row['update_ms_median']:6.1f} ms"
              f"{acc}", flush=True)
    mcb = rows[0]["published_bytes"]
    for row in rows[1:3]:
        print(f"published {row['system']} / multiclass-bayes: "
              f"{row['published_bytes'] / mcb:.2f}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)


if __name__ == "__main__":
    main()
