"""``evsmap map``: integrate a sequence into a volumetric (semantic) map and measure it."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from evsmap.cli.options import key_value, positive_float, positive_int
from evsmap.cli.outputs import Output, claim_outputs
from evsmap.cli.precision import add_precision_options, apply_precision, backend_for
from evsmap.cli.sequence_args import add_sequence_options, reader_options, skipped_warning
from evsmap.cli.weights_args import add_weights_options, announce_weights, make_segmenter
from evsmap.errors import EvsmapError
from evsmap.interfaces import FILE_FORMATS
from evsmap.mapping.options import OCTREE_DEFAULTS
from evsmap.readers.detect import open_sequence
from evsmap.readers.skipping import SkippedFrames

_NOISE = "the classes in the map are noise"
"""What random weights make meaningless in a semantic map."""


def _range(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of metres, got {text!r}") from None
    if value != value or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    if value == 0:
        raise argparse.ArgumentTypeError("0 m inserts nothing: give a positive range, or a "
                                         "negative one for no limit")
    return value


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "map", help="integrate a sequence into a map and report rate and size",
        description="Integrate SEQUENCE (any reader's path, or 'synthetic' for the built-in "
                    "scene) with the map updater NAME; semantic updaters take the per-pixel "
                    "top-3 of --segmenter (a network, or 'oracle' for the ground-truth labels "
                    "with noise). Reports the update rate alone and with segmentation, the map "
                    "file's size and the in-memory size.")
    p.add_argument("sequence", metavar="SEQUENCE", help="a sequence folder or 'synthetic'")
    p.add_argument("--updater", required=True, metavar="NAME", help="map updater (evsmap list)")
    p.add_argument("--segmenter", metavar="NAME",
                   help="segmenter for semantic updaters (default: oracle when the sequence has "
                        "labels)")
    add_weights_options(p, depends="The classes in a semantic map")
    p.add_argument("--backend", choices=("torch", "onnxruntime"),
                   help="inference backend of a network segmenter (default torch)")
    p.add_argument("--resolution", type=positive_float, default=OCTREE_DEFAULTS.resolution,
                   metavar="R", help=f"leaf size in metres (default {OCTREE_DEFAULTS.resolution})")
    p.add_argument("--max-range", type=_range, default=OCTREE_DEFAULTS.max_range, metavar="M",
                   help=f"sensor max range in metres, negative for unlimited (default "
                        f"{OCTREE_DEFAULTS.max_range:g})")
    p.add_argument("--frames", type=positive_int, metavar="N", help="first N frames only")
    p.add_argument("--out", type=Path, metavar="FILE",
                   help="write the map here (.ot full state; .bt occupancy only); an existing "
                        "file is refused unless --overwrite")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing --out or --ply file (once the new one is "
                        "complete)")
    p.add_argument("--file-format", choices=FILE_FORMATS, default="full",
                   metavar="|".join(FILE_FORMATS),
                   help="--out .ot content: full (the whole state; reloads and mapping "
                        "continues), published (the file the compared system itself saves: "
                        "a ColorOcTree of the top class's colour for classic-semantic and "
                        "multiclass-bayes), colour (a ColorOcTree any OctoMap tool opens: one "
                        "colour a node, the top class's) or message (multiclass-bayes only: "
                        "SSMI's octomap_full message nodes with their semantics, under the id "
                        "SSMISemanticOcTreeMessage); default full")
    p.add_argument("--ply", type=Path, metavar="FILE",
                   help="also write the occupied voxel centres as a binary PLY point cloud")
    p.add_argument("--ply-color", choices=("rgb", "class"), metavar="rgb|class",
                   help="colour the PLY points by stored colour or by class (default: class for "
                        "semantic updaters, rgb otherwise)")
    p.add_argument("-o", "--option", type=key_value, action="append", default=[],
                   metavar="KEY=VALUE", help="an updater option, repeatable (e.g. theta=0.6)")
    p.add_argument("-s", "--segmenter-option", type=key_value, action="append", default=[],
                   metavar="KEY=VALUE",
                   help="a segmenter option, repeatable (e.g. -s accuracy=0.9 for the oracle, "
                        "-s dataset=cityscapes)")
    p.add_argument("--pipeline", action=argparse.BooleanOptionalAction, default=True,
                   help="overlap reading, segmentation and the map update of consecutive frames "
                        "(the same map; default on); --no-pipeline runs them one after the "
                        "other")
    p.add_argument("--stage-threads", type=key_value, action="append", default=[],
                   metavar="KEY=N",
                   help="a stage's threads, repeatable: segment (ONNX Runtime), torch (pre- and "
                        "post-processing), update (the update kernels), blas (numpy), over "
                        "the plan for --cores; recorded in the JSON")
    p.add_argument("--cores", type=positive_int, metavar="N",
                   help="plan the pipelined loop's threads for N cores (1 to 1024; default: "
                        "the cores this process may run on); the plan and why is the JSON's "
                        "thread_plan (docs/realtime.md, \"Each stage's threads\")")
    p.add_argument("--json", action="store_true", help="print the record as JSON")
    add_precision_options(p, target="the frames mapped")
    add_sequence_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from evsmap.interrupt import file_state, set_resume_hint

    claim_outputs([None if args.out is None else Output("--out", args.out,
                                                        suffixes=(".ot", ".bt")),
                   None if args.ply is None else Output("--ply", args.ply)],
                  overwrite=args.overwrite)
    before = file_state(args.out)

    def hint() -> str:
        if args.out is not None and file_state(args.out) != before:
            return f"the map was complete before that: {args.out} is written"
        return "no map was written (a map file is written whole or not at all); run the " \
               "same command again"

    set_resume_hint(hint)
    from evsmap.measure.mapping import map_sequence
    from evsmap.measure.pipelined import loop_balance
    from evsmap.progress import progress
    from evsmap.registry import UPDATERS

    plan = _thread_plan(args)
    config = dict(args.option)
    config.update(resolution=args.resolution, max_range=args.max_range)
    updater = UPDATERS.create(args.updater, **config)
    ply_color = None
    if args.ply is not None:
        if not updater.has_leaf_map:
            raise EvsmapError(f"--ply: updater {args.updater!r} keeps its map in C++ OctoMap, "
                              f"which evsmap cannot list as points; write it with --out (.ot or "
                              f".bt, for octovis) or map with one of evsmap's updaters")
        from evsmap.updaters.export import check_color_by

        ply_color = check_color_by(updater, args.ply_color)
    sequence = _open(args)
    segmenter, seg_name, weights_record = _segmenter(args, updater, sequence)
    if segmenter is None and (args.precision != "fp32" or args.device != "cpu"):
        option = f"--precision {args.precision}" if args.precision != "fp32" \
            else f"--device {args.device}"
        raise EvsmapError(f"{option}: updater {args.updater!r} runs no segmenter (pass "
                          f"--segmenter NAME, a network)")
    precision = {} if segmenter is None or seg_name is None else apply_precision(
        args, segmenter, sequence, name=seg_name, count=args.frames, what="map")
    count = len(sequence) if args.frames is None else min(args.frames, len(sequence))
    if seg_name is not None:  # a segmenter runs
        announce_weights(args, seg_name, weights_record, command="evsmap map",
                         depends=updater.uses_semantics, noise=_NOISE)
    survey = _survey(sequence, count, args.max_range, skip_bad=args.skip_bad)
    from evsmap.environment import describe

    record = map_sequence(
        sequence, updater, updater_name=args.updater, segmenter=segmenter,
        segmenter_name=seg_name, frames=args.frames, out=args.out,
        progress=lambda it: progress(it, total=len(it), desc=f"mapping {args.updater}"),
        skip_bad=args.skip_bad, file_format=args.file_format, pipeline=args.pipeline,
        threads=plan.threads)
    result = record.as_dict()
    result.update(precision)
    result.update(weights_record)
    result["stage_ms_median"] = record.stage_medians()
    result["thread_plan"] = plan.as_dict()
    result["loop"] = loop_balance(result["stage_ms_median"], record.wall_hz,
                                  pipelined=args.pipeline)
    result["machine"] = describe()
    result["occupied_voxels"] = updater.occupied_voxels()
    if survey is not None:
        result["range_survey"] = survey.as_dict()
    truth = _ground_truth(sequence, args.resolution)
    if truth is not None and updater.has_leaf_map:
        from evsmap.metrics import evaluate_map

        quality = evaluate_map(updater, truth).as_dict()
        quality.pop("semantics", None)
        result["quality"] = quality
    if args.ply is not None and result["occupied_voxels"]:
        from evsmap.updaters.export import export_ply

        result["ply_points"] = export_ply(updater, args.ply, color_by=ply_color)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(format_record(result))
    for line in empty_result_warnings(result, args):
        sys.stderr.write(f"evsmap map: warning: {line}\n")
    return 0


def _thread_plan(args: argparse.Namespace):
    """The loop's threads: the plan for ``--cores`` (default: this process's CPUs) and
    ``--device``, with ``--stage-threads`` over it (:mod:`evsmap.measure.thread_plan`)."""
    from dataclasses import replace

    from evsmap.measure.pipelined import stage_thread_changes
    from evsmap.measure.thread_plan import available_cores, thread_plan

    cores = available_cores() if args.cores is None else args.cores
    plan = thread_plan(cores, args.device, pipelined=args.pipeline)
    if args.cores is not None:
        plan = replace(plan, cores_from="--cores")
    return plan.overridden(stage_thread_changes(args.stage_threads))


def _open(args: argparse.Namespace):
    """The sequence to map (the synthetic room read as a recorded sequence, as Table IV reads
    it: rendered once into the cache; ``-r render=live`` renders each frame in the loop)."""
    sequence = open_sequence(args.sequence, args.reader, reader_options(args, args.sequence))
    if not sequence.has_poses:
        hint = sequence.meta.get("no_poses_hint")  # e.g. synthrooms: pick one room
        raise EvsmapError(
            f"{args.sequence}: {hint}" if hint else
            f"{args.sequence}: {sequence.meta.get('layout', 'this dataset')} has no camera poses "
            f"(a segmentation dataset); map a sequence with poses (TUM, a ROS bag, synthetic)")
    return sequence


def _segmenter(args: argparse.Namespace, updater, sequence) -> tuple[Any, str | None, dict]:
    """The segmenter the updater reads (the oracle by default where the sequence has labels),
    its name and the record's weights fields; (None, None, {}) where none runs."""

    seg_name = args.segmenter
    if not (updater.uses_semantics or seg_name):
        if args.segmenter_option:
            raise EvsmapError(f"-s: updater {args.updater!r} uses no segmenter (pass "
                              f"--segmenter NAME to run one)")
        if args.weights is not None:
            raise EvsmapError(f"--weights {args.weights}: updater {args.updater!r} runs no "
                              f"segmenter (pass --segmenter NAME, a network, to time one)")
        return None, None, {}
    if seg_name is None:
        if len(sequence) and sequence.frame(0).labels is None:
            raise EvsmapError(
                f"updater {args.updater!r} needs semantics and {sequence.name!r} has no "
                f"ground-truth labels for the oracle: pass --segmenter NAME (a network, see "
                f"`evsmap list`) with --weights FILE")
        seg_name = "oracle"
    seg_config: dict[str, Any] = dict(args.segmenter_option)
    backend = backend_for(args, seg_name)
    if backend is not None:
        seg_config["backend"] = backend
    segmenter, fields = make_segmenter(args, seg_name, seg_config, command="evsmap map",
                                       depends=updater.uses_semantics, noise=_NOISE)
    return segmenter, seg_name, fields


def _survey(sequence, count: int, max_range: float, *, skip_bad: bool):
    """The ranges of up to 3 frames (first, middle, last) before mapping, and a warning at once
    when most of their points lie beyond ``max_range`` (None with no limit)."""
    if max_range < 0 or count == 0:
        return None
    from evsmap.measure.range_survey import survey_indices, survey_ranges

    frames = []
    for i in survey_indices(count):
        try:
            frames.append((i, sequence.frame(i)))
        except EvsmapError:
            if not skip_bad:
                raise
    survey = survey_ranges(frames, max_range)
    line = range_warning(survey)
    if line:
        sys.stderr.write(f"evsmap map: warning: {line}\n")
    return survey


def range_warning(survey) -> str | None:
    """The warning for a survey where most points lie beyond ``--max-range``, else None."""
    if survey.points == 0 or survey.share_beyond <= 0.5:
        return None
    frames = ", ".join(str(i) for i in survey.frames)
    return (f"{100 * survey.share_beyond:.0f} % of the points of frames {frames} lie beyond "
            f"--max-range {survey.max_range:g} m (their distances: {survey.min_m:.1f} to "
            f"{survey.max_m:.1f} m, median {survey.median_m:.1f} m); those rays insert free "
            f"space only. Pass --max-range {math.ceil(survey.p95_m)} to keep 95 % of them, or "
            f"-1 for no limit")


def empty_result_warnings(r: dict[str, Any], args: argparse.Namespace) -> list[str]:
    """Warnings for a run that succeeded and holds (almost) nothing: no occupied voxel, most
    frames skipped."""
    lines = []
    skipped = skipped_warning(r.get("extra", {}).get("skipped"), r["frames"])
    if skipped:
        lines.append(skipped)
    if r.get("occupied_voxels") == 0:
        why = ""
        survey = r.get("range_survey")
        if survey and survey["share_beyond"] > 0.5:
            why = f" (most points lie beyond --max-range {args.max_range:g} m, see above)"
        elif r["frames"] == 0:
            why = " (no frame was mapped)"
        lines.append(f"the map holds no occupied voxel, only free space{why}"
                     + ("; no PLY was written" if args.ply is not None else ""))
    return lines


def _ground_truth(sequence, resolution: float):
    """The sequence's ground-truth voxels at ``resolution`` when it has them (the synthetic
    scenes, one synthrooms room, a ScanNet scene with its labelled mesh), else None."""
    if not sequence.has_ground_truth:
        return None
    try:
        return sequence.ground_truth(resolution)
    except EvsmapError:
        return None


def _other_size(r: dict[str, Any]) -> str:
    sizes = [(fmt, r.get(f"map_bytes_{fmt}")) for fmt in FILE_FORMATS
             if fmt != r["file_format"]]
    return "".join(f"; {fmt} .ot {size / 1e6:.3f} MB" for fmt, size in sizes
                   if size is not None)


def _front_end_line(fe: dict[str, Any] | None) -> list[str]:
    if not fe or not fe.get("name"):
        return []
    per = [(k, fe.get(k) or []) for k in ("centroids", "hits", "rays")]
    text = ", ".join(f"{k} {sum(v) / len(v):,.0f}" for k, v in per if v)
    return [f"front end    {fe['name']}" + (f" ({text} a frame, means)" if text else "")]


def _pct(x) -> str:
    return "n/a" if x is None or x != x else f"{100.0 * x:.1f} %"


def format_record(r: dict[str, Any]) -> str:
    seg = r["segmenter"] or "none"
    ply = [f"point cloud  {r['ply_points']:,} points"] if "ply_points" in r else []
    skipped = r.get("extra", {}).get("skipped")
    if skipped is not None:
        ply.append("skipped      " + SkippedFrames(
            [(f["index"], f["reason"]) for f in skipped["frames"]]).summary())
    return "\n".join([
        f"updater      {r['updater']}  (segmenter {seg}, {r['frames']} frames of "
        f"{r['sequence']}, {r['resolution']:.4g} m)",
        f"update       {r['update_hz']:.2f} Hz median (map update only)",
        f"wall         {r['wall_hz']:.2f} Hz (frames / wall time, reading included, "
        f"{'pipelined' if r['pipeline'].get('enabled') else 'one stage after the other'})",
        f"seg + update {r['segment_update_hz']:.2f} Hz median (" + (
            "segmentation + update per frame, Table IV's runtime)" if r["segment_ms"]
            else "update only: no network ran)"),
        "per frame    " + ", ".join(f"{k} {v:.1f} ms" for k, v in
                                    r.get("stage_ms_median", {}).items()) + " (medians)",
    ] + _loop_lines(r.get("loop"), r.get("wall_hz")) + _plan_lines(r.get("thread_plan")) + [
        f"map file     {r['map_bytes'] / 1e6:.3f} MB {r['file_format']}" + (
            f"  ({r['map_file']})" if r["map_file"] else "") + _other_size(r),
        f"map          {r['nodes']:,} nodes, {r['leaves']:,} leaves",
        "memory       " + _memory_text(r),
    ] + _network_lines(r) + _front_end_line(r.get("front_end"))
        + _machine_lines(r.get("machine")) + ply
        + ([f"note         {r['extra']['segmenter_not_run']}"]
           if r.get("extra", {}).get("segmenter_not_run") else [])
        + _quality_lines(r.get("quality")))


def _loop_lines(loop: dict[str, Any] | None, wall_hz: float | None) -> list[str]:
    """The wall rate beside the rate the loop's stages allow, and each stage's share of a
    frame's wall time (:func:`~evsmap.measure.pipelined.loop_balance`)."""
    if not loop or not wall_hz:
        return []
    bound_hz = 1000.0 / loop["bound_ms"] if loop["bound_ms"] > 0 else float("inf")
    if loop["bound"] == "all stages":
        what = f"of the rate its stages allow one after the other ({loop['bound_ms']:.1f} ms"
    else:
        what = f"of its slowest stage's rate ({loop['bound']} {loop['bound_ms']:.1f} ms"
    shares = ", ".join(f"{k} {100 * v:.0f} %" for k, v in loop["shares"].items())
    return [f"loop         reaches {100 * loop['reached']:.0f} % {what} a frame: "
            f"{bound_hz:.2f} Hz; wall {wall_hz:.2f} Hz)",
            f"shares       {shares} of the wall time a frame"
            + (" (the stages overlap)" if loop["bound"] != "all stages" else "")]


def _plan_lines(plan: dict[str, Any] | None) -> list[str]:
    """The loop's threads and the cores they were planned for."""
    if not plan:
        return []
    stages = plan["stages"]
    text = ", ".join(f"{k} {'default' if v['threads'] is None else v['threads']}"
                     for k, v in stages.items() if k != "read")
    source = "--cores" if plan["cores_from"] == "--cores" else "the process's CPUs"
    return [f"threads      {text} ({plan['loop']} loop planned for {plan['cores']} cores, "
            f"{source}; network on {plan['device']})"]


def _network_lines(r: dict[str, Any]) -> list[str]:
    """The network's precision (with the int8 scheme) and post-processing path, where a network
    ran."""
    if "precision" not in r:
        return []
    text = r["precision"]
    if r["precision"] == "int8":
        text += f" {r.get('int8_scheme')} ({r.get('int8_scheme_chosen_by')})"
    post = r.get("postprocess", "network")
    text += f", postprocess {post}" + (" (the faithful path)" if post == "network" else "")
    if r.get("device"):
        text += f", on {r['device']}"
    lines = [f"network      {text}"]
    if r.get("gpu"):
        from evsmap.cli.speed_cmd import gpu_text

        lines.append(f"gpu          {gpu_text(r['gpu'])}")
    return lines


def _machine_lines(m: dict[str, Any] | None) -> list[str]:
    if not m:
        return []
    return [f"machine      {m['cpu']} ({m['instruction_set']}, {m['cpus']} CPUs)"]


def _memory_text(r: dict[str, Any]) -> str:
    """Measured memory first (the map's arrays, the run's peak RSS), then the formula."""
    parts = []
    if r.get("map_nbytes") is not None:
        parts.append(f"map arrays {r['map_nbytes'] / 1e6:.3f} MB")
    if r.get("peak_rss_bytes") is not None:
        since = "run" if r.get("peak_scope") == "run" else "process"
        parts.append(f"peak RSS {r['peak_rss_bytes'] / 1e6:.0f} MB (the {since}'s; "
                     f"{r['start_rss_bytes'] / 1e6:.0f} MB at its start)")
    parts = [", ".join(parts) + " (measured)"] if parts else []
    if r.get("octomap_memory_bytes") is not None:
        parts.append(f"OctoMap memoryUsage() formula "
                     f"{r['octomap_memory_bytes'] / 1e6:.3f} MB")
    return "; ".join(parts) or "not measured"


def _quality_lines(q: dict[str, Any] | None) -> list[str]:
    if q is None:
        return []
    lines = [f"geometry     precision {_pct(q['precision'])}, recall {_pct(q['recall'])} "
             f"(occupied leaves against the scene's ground-truth voxels, "
             f"{q['slack_voxels']} voxel slack)"]
    if q.get("semantic_accuracy") is not None:
        lines.append(f"semantics    accuracy {_pct(q['semantic_accuracy'])}, mIoU "
                     f"{_pct(q['map_miou'])} over {q['matched'] - q['unlabelled']:,} matched "
                     f"labelled leaves")
        if q.get("scene_miou") is not None:
            lines.append(f"             scene mIoU {_pct(q['scene_miou'])} over the "
                         f"{q['observed']:,} observed ground-truth voxels (one the map dropped "
                         f"is a miss)")
        if q.get("unlabelled"):
            lines.append(f"             {q['unlabelled']:,} matched leaves hold no class; "
                         f"counted as wrong the accuracy is "
                         f"{_pct(q['semantic_accuracy_all'])}")
    return lines
