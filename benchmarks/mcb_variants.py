"""Compare multiclass-bayes's leaf updates with classic-semantic on the built-in synthetic room:
3D semantic accuracy and mIoU against the room's ground-truth voxels, nodes and the pruned share
of the leaves, at several accuracies of the oracle's `per-pixel` profile. The same observations
feed every updater.

    python benchmarks/mcb_variants.py [--resolution 0.05] [--frames 60] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from evsmap.metrics import evaluate_map
from evsmap.registry import READERS, SEGMENTERS, UPDATERS

SYSTEMS = {
    "multiclass-bayes (paper: eq. 7, printed pairing)": ("multiclass-bayes", {}),
    "multiclass-bayes pairing=ssmi": ("multiclass-bayes", {"pairing": "ssmi"}),
    "multiclass-bayes leaf_update=average": ("multiclass-bayes", {"leaf_update": "average"}),
    "multiclass-bayes leaf_update=average occupancy=octomap (evsmap before)":
        ("multiclass-bayes", {"leaf_update": "average", "occupancy": "octomap"}),
    "classic-semantic": ("classic-semantic", {}),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=float, default=0.05)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--accuracies", default="0.7,0.85,0.95")
    ap.add_argument("--json")
    args = ap.parse_args()
    seq = READERS.create("synthetic", frames=args.frames)
    frames = [seq.frame(i) for i in range(len(seq))]
    truth = seq.ground_truth(args.resolution)
    rows = []
    for acc in (float(a) for a in args.accuracies.split(",")):
        oracle = SEGMENTERS.create("oracle", profile="per-pixel", accuracy=acc)
        obs = [oracle.predict(f) for f in frames]
        for label, (name, options) in SYSTEMS.items():
            m = UPDATERS.create(name, resolution=args.resolution, max_range=5.0, **options)
            t0 = time.perf_counter()
            for f, o in zip(frames, obs, strict=True):
                m.integrate(f, o)
            seconds = time.perf_counter() - t0
            q = evaluate_map(m, truth)
            tree = m.tree()
            finest = int(np.count_nonzero(tree.is_leaf & (tree.depth == 16)))
            rows.append({"oracle_accuracy": acc, "system": label,
                         "semantic_accuracy": q.semantic_accuracy, "map_miou": q.map_miou,
                         "precision": q.precision, "recall": q.recall,
                         "nodes": tree.num_nodes, "leaves": tree.num_leaves,
                         "finest_leaves": m.map.num_leaves,
                         "pruned_share": 1.0 - finest / m.map.num_leaves,
                         "seconds": seconds})
            r = rows[-1]
            print(f"{acc:.2f}  {label:<72} acc {100 * r['semantic_accuracy']:5.1f} %  "
                  f"mIoU {100 * r['map_miou']:5.1f} %  nodes {r['nodes']:>8,}  "
                  f"pruned {100 * r['pruned_share']:4.1f} %  prec {100 * r['precision']:5.1f} "
                  f"rec {100 * r['recall']:5.1f}", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)


if __name__ == "__main__":
    main()
