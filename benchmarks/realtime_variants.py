"""What each post-processing path costs in accuracy (issue 40): 2D and 3D, against the faithful
one, on trained weights.

    python benchmarks/realtime_variants.py --weights feagnet-v1=V1.pt --weights feagnet-v2=V2.pt \
        --dataset DIR [--frames 60] [--precision int8] [--out reports/realtime/variants.json]

For every network given and every ``postprocess`` (:data:`evsmap.segmenters.network.
POSTPROCESSES`; ``network`` is the faithful path):

* **2D** on the dataset's test split (a prepared ``synthrooms`` folder: the proxy weights'
  own benchmark): mIoU, and the share of labelled pixels whose top-1 class equals the faithful
  path's (agreement);
* **3D** on the synthetic room (``evsmap map synthetic``'s 60 frames, 5 cm, max range 5 m,
  EVSMap = ``multiclass-bayes``): the map mIoU against the room's ground truth, and the share
  of the faithful map's occupied labelled leaves that the variant's map holds occupied with
  the same class (map agreement).

A variant that loses more than :data:`BUDGET_2D` points of 2D mIoU or :data:`BUDGET_3D` of 3D
map mIoU is reported but not recommended (the issue's budget). Timing is not measured here
(``nox -s bench -- -k realtime``): the figures are exact scores of deterministic runs.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

BUDGET_2D = 1.0
BUDGET_3D = 0.5


def _segmenter(name: str, weights: str, path: str, precision: str, calibration):
    """``path``: a ``postprocess`` name, or ``stride@HxW`` (the stride variant with the network
    run at input size HxW)."""
    from evsmap.registry import SEGMENTERS

    backend = "onnxruntime" if precision == "int8" else "torch"
    postprocess, _, size = path.partition("@")
    options = {"input_size": size} if size else {}
    seg = SEGMENTERS.create(name, weights=weights, backend=backend, postprocess=postprocess,
                            **options)
    if precision == "int8":
        seg.calibrate(calibration, source="synthrooms train split, 16 evenly spaced frames")
    return seg


def _scores_2d(seg, frames, faithful: list[np.ndarray] | None):
    from evsmap.metrics.segmentation import ConfusionMatrix

    confusion = ConfusionMatrix(seg.num_classes)
    labels, same, counted = [], 0, 0
    for i, frame in enumerate(frames):
        top = seg.predict(frame).argmax
        labels.append(top)
        confusion.update(top, frame.labels)
        valid = frame.labels != 255
        if faithful is not None:
            same += int(np.count_nonzero(top[valid] == faithful[i][valid]))
            counted += int(np.count_nonzero(valid))
    miou = confusion.result().miou
    return labels, {"miou": 100 * float(miou),
                    "agreement": None if faithful is None else 100 * same / max(counted, 1)}


def _map_3d(seg, sequence):
    from evsmap.measure.mapping import map_sequence
    from evsmap.metrics import evaluate_map
    from evsmap.registry import UPDATERS

    updater = UPDATERS.create("multiclass-bayes", resolution=0.05, max_range=5.0)
    record = map_sequence(sequence, updater, updater_name="multiclass-bayes", segmenter=seg,
                          segmenter_name=seg.name, pipeline=True)
    quality = evaluate_map(updater, sequence.ground_truth(0.05)).as_dict()
    return updater.occupied_labels(), record, quality


def _map_agreement(faithful, other) -> float:
    codes, labels = faithful
    ocodes, olabels = other
    keep = labels >= 0
    pos = np.searchsorted(ocodes, codes[keep])
    found = (pos < len(ocodes)) & (ocodes[np.minimum(pos, len(ocodes) - 1)] == codes[keep])
    same = found & (olabels[np.minimum(pos, len(ocodes) - 1)] == labels[keep])
    return 100 * float(np.count_nonzero(same)) / max(int(np.count_nonzero(keep)), 1)


def main(argv: list[str] | None = None) -> int:
    from evsmap.datasets.lookup import open_dataset
    from evsmap.environment import describe
    from evsmap.registry import READERS
    from evsmap.segmenters.network import POSTPROCESSES
    from evsmap.segmenters.quantize import evenly_spaced

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--weights", action="append", required=True, metavar="NAME=FILE")
    ap.add_argument("--dataset", required=True, help="a prepared synthrooms folder")
    ap.add_argument("--precision", default="int8", choices=("fp32", "int8"))
    ap.add_argument("--frames", type=int, default=60, help="synthetic-room frames mapped")
    ap.add_argument("--out", default="reports/realtime/variants.json")
    ap.add_argument("--input-size", action="append", default=[], metavar="HxW",
                    help="also the stride variant with the network at this input size")
    args = ap.parse_args(argv)
    test, _ = open_dataset(args.dataset, split="test")
    train, _ = open_dataset(args.dataset, split="train")
    frames = [test.frame(i) for i in range(len(test))]
    calibration = [train.frame(i) for i in evenly_spaced(len(train), 16)]
    room = READERS.create("synthetic", render="cached", frames=args.frames)
    room_calibration = [room.frame(i) for i in evenly_spaced(len(room), 16)]
    result: dict = {"machine": describe(), "precision": args.precision, "networks": {}}
    for item in args.weights:
        name, _, weights = item.partition("=")
        rows: dict = {}
        faithful_2d = faithful_3d = None
        for post in (*POSTPROCESSES, *(f"stride@{size}" for size in args.input_size)):
            seg = _segmenter(name, weights, post, args.precision, calibration)
            labels, scores = _scores_2d(seg, frames, faithful_2d)
            seg = _segmenter(name, weights, post, args.precision, room_calibration)
            leaves, record, quality = _map_3d(seg, room)
            row = {"miou_2d": scores["miou"], "agreement_2d": scores["agreement"],
                   "map_miou": 100 * quality["map_miou"],
                   "scene_miou": 100 * quality["scene_miou"],
                   "map_agreement": None if faithful_3d is None
                   else _map_agreement(faithful_3d, leaves),
                   "wall_hz": record.wall_hz, "stage_ms_median": record.stage_medians()}
            if post == "network":
                faithful_2d, faithful_3d = labels, leaves
            else:
                base = rows["network"]
                row["cost_2d"] = base["miou_2d"] - row["miou_2d"]
                row["cost_3d"] = base["map_miou"] - row["map_miou"]
                row["within_budget"] = bool(row["cost_2d"] <= BUDGET_2D
                                            and row["cost_3d"] <= BUDGET_3D)
            rows[post] = row
            print(f"{name} {post:8s} 2D mIoU {row['miou_2d']:6.2f} agreement "
                  f"{row['agreement_2d'] or 100:6.2f}  3D map mIoU {row['map_miou']:6.2f} "
                  f"map agreement {row['map_agreement'] or 100:6.2f}  "
                  f"{row['wall_hz']:5.2f} Hz", file=sys.stderr)
        result["networks"][name] = rows
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
