"""``evsmap eval``: score a segmenter on a labelled dataset (mIoU, pixel accuracy, per-class IoU).

One confusion matrix is summed over every labelled pixel of the split (void pixels left out),
as the paper's MIoU columns (Tables I-III) and detectron2's ``SemSegEvaluator`` compute it; see
:mod:`evsmap.metrics.segmentation`.

A network segmenter without ``--weights`` is refused: its random initialisation scores noise,
and a printed mIoU would look like a result. ``--allow-random`` runs it anyway (to check the
pipeline), seeded by ``--seed``, warns on stderr and marks the record ``"random_weights": true``
with its ``init_seed`` (:mod:`evsmap.cli.weights_args`).
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from evsmap.cli.options import key_value, positive_int
from evsmap.cli.precision import add_precision_options, apply_precision, backend_for
from evsmap.cli.sequence_args import add_sequence_options, skipped_warning
from evsmap.cli.weights_args import add_weights_options, announce_weights, make_segmenter
from evsmap.datasets.lookup import dataset_classes, open_dataset
from evsmap.errors import EvsmapError


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "eval", help="score a segmenter on a labelled dataset (mIoU, per-class IoU)",
        description="Run MODEL over every frame of a labelled dataset split and report the "
                    "dataset-level mIoU, pixel accuracy, mean accuracy and per-class IoU "
                    "(one confusion matrix over all labelled pixels, void pixels ignored). "
                    "NAME-or-PATH is a dataset folder (reader detected, or --reader), a "
                    "prepared dataset's name (looked up in datasets/NAME and the data root) "
                    "or a reader that needs no path (e.g. synthetic). A network without "
                    "--weights is refused unless --allow-random.")
    p.add_argument("model", metavar="MODEL", help="segmenter name (evsmap list)")
    p.add_argument("--dataset", required=True, metavar="NAME-or-PATH",
                   help="labelled dataset: a folder, a prepared dataset's name, or 'synthetic'")
    p.add_argument("--split", metavar="SPLIT",
                   help="dataset split for readers that have splits (default: test; val for "
                        "cityscapes)")
    p.add_argument("--limit", type=positive_int, metavar="N", help="first N frames only")
    add_weights_options(p, depends="Its scores")
    p.add_argument("--backend", choices=("torch", "onnxruntime"),
                   help="inference backend of a network segmenter (default torch)")
    p.add_argument("-o", "--option", type=key_value, action="append", default=[],
                   metavar="KEY=VALUE",
                   help="a segmenter option, repeatable (e.g. -o num_classes=37, -o accuracy=0.9)")
    add_precision_options(p, target="the frames scored")
    add_sequence_options(p)
    p.add_argument("--json", action="store_true", help="print the record as JSON")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from evsmap.classes import class_names_for
    from evsmap.measure.engine import run_segmentation
    from evsmap.measure.evaluators import ConfusionEvaluator
    from evsmap.progress import progress

    config: dict[str, Any] = dict(args.option)
    backend = backend_for(args, args.model)
    if backend is not None:
        config["backend"] = backend
    noise = "its scores mean nothing"
    segmenter, weights_record = make_segmenter(args, args.model, config, command="evsmap eval",
                                               depends=True, noise=noise)

    sequence, source = open_dataset(args.dataset, reader=args.reader, split=args.split,
                                    limit=args.limit, options=args.reader_option)
    n_data, data_names = dataset_classes(sequence)
    n_seg = int(segmenter.num_classes)
    if n_data is not None and n_data != n_seg:
        raise EvsmapError(
            f"{args.model} predicts {n_seg} classes but {sequence.name!r} is labelled with "
            f"{n_data}: use a model for this label set (e.g. -o num_classes={n_data} with "
            f"matching --weights)")
    names = data_names if len(data_names) == n_seg else \
        tuple(segmenter.class_names or class_names_for(n_seg))

    total = len(sequence) if args.limit is None else min(args.limit, len(sequence))
    if total == 0:
        raise EvsmapError(f"{sequence.name!r} ({source['reader']}, split "
                          f"{source['split']}) has no frames")
    announce_weights(args, args.model, weights_record, command="evsmap eval", depends=True,
                     noise=noise)
    precision = apply_precision(args, segmenter, sequence, name=args.model, count=total,
                                what="eval")
    scored = run_segmentation(
        sequence, segmenter, frames=total, skip_bad=args.skip_bad,
        progress=lambda it: progress(it, total=total, desc=f"evaluating {args.model}"),
        evaluators=[ConfusionEvaluator(num_classes=n_seg, class_names=names,
                                       source=sequence.name)])
    result = scored.results["confusion"]
    frames = scored.frames
    seconds = sum(scored.predict_ms) / 1000.0
    from evsmap.environment import describe

    record = {
        "model": args.model, "options": config, **weights_record,
        "backend": segmenter.backend, **precision,
        "dataset": sequence.name, "reader": source["reader"], "split": source["split"],
        "frames": frames, "skipped": scored.skipped.as_dict() if args.skip_bad else None,
        "seconds_per_frame": seconds / frames if frames else None,
        **result.as_dict(),
        "machine": describe(),
    }
    if args.json:
        print(json.dumps(record, indent=2))
    else:
        print(format_eval(record))
    warning = skipped_warning(record["skipped"], frames)
    if warning:
        sys.stderr.write(f"evsmap eval: warning: {warning}\n")
    return 0


def _pct(x: float | None) -> str:
    return "n/a" if x is None else f"{100.0 * x:.2f} %"


def format_eval(r: dict[str, Any]) -> str:
    split = f", split {r['split']}" if r["split"] else ""
    weights = r["weights"] or (f"RANDOM, seed {r['init_seed']}: scores meaningless"
                               if r["random_weights"] else "none")
    lines = [
        f"model            {r['model']}  (weights: {weights}"
        + (f"; int8 {r['int8_scheme']} on {r['instruction_set']}" if r.get("precision") == "int8"
           else "") + ")",
        f"dataset          {r['dataset']}  ({r['reader']}{split}, {r['frames']} frames, "
        f"{r['pixels']:,} labelled pixels)",
        f"mIoU             {_pct(r['miou'])}  over {r['present_classes']} of "
        f"{r['num_classes']} classes",
        f"pixel accuracy   {_pct(r['pixel_accuracy'])}",
        f"mean accuracy    {_pct(r['mean_accuracy'])}",
        f"fw IoU           {_pct(r['frequency_weighted_iou'])}",
    ]
    if r.get("skipped"):
        lines.append(f"skipped          {r['skipped']['count']} bad frame(s)")
    per_class = r["per_class_iou"]
    if per_class:
        width = max(len(n) for n in per_class)
        lines.append("per-class IoU (classes present in ground truth or prediction)")
        lines += [f"  {name:<{width}}  {_pct(v)}" for name, v in per_class.items()]
    return "\n".join(lines)
