"""``evsmap info``: what a sequence folder holds."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from evsmap.cli.sequence_args import add_sequence_options, reader_options
from evsmap.errors import EvsmapError
from evsmap.progress import progress
from evsmap.readers.detect import open_sequence, sequence_reader
from evsmap.readers.skipping import SkippedFrames
from evsmap.registry import READERS
from evsmap.summary import summarize_sequence


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "info", help="describe a sequence folder (layout, frames, depth, poses, labels)",
        description="Detect the layout of PATH (TUM RGB-D, evsmap synthetic, Microsoft 7-Scenes, "
                    "...) and print the number of frames, resolution, depth range, pose span and "
                    "label classes.")
    p.add_argument("path", type=Path, metavar="PATH",
                   help="a sequence folder or bag, or a reader that needs no path (synthetic)")
    p.add_argument("--json", action="store_true", help="print the record as JSON")
    p.add_argument("--camera", metavar="NAME",
                   help="TUM camera intrinsics when the folder name does not tell "
                        "(fr1, fr2, fr3, ros-default)")
    add_sequence_options(p)
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    name = sequence_reader(str(args.path), args.reader)
    options = reader_options(args, str(args.path))
    if args.camera:
        if not READERS.get(name).takes.camera:
            raise EvsmapError(f"--camera does not apply to reader {name!r}")
        options.append(("camera", args.camera))
    seq = open_sequence(str(args.path), name, options)
    skipped = SkippedFrames()
    record = {"reader": name, **summarize_sequence(
        seq, progress=lambda frames: progress(frames, total=len(seq), desc="reading"),
        skip_bad=args.skip_bad, skipped=skipped)}
    if args.skip_bad:
        record["skipped"] = skipped.as_dict()
    if args.json:
        print(json.dumps(record, indent=2))
    else:
        print(format_info(record))
    return 0


def format_info(r: dict) -> str:
    lines = [
        f"path        {r.get('name')}  (layout: {r['layout']}, reader: {r['reader']})",
        f"frames      {r['frames']}",
    ]
    if "intrinsics" in r:
        lines.append(
            f"resolution  {r['width']}x{r['height']}  fx {r['intrinsics']['fx']:.2f} "
            f"fy {r['intrinsics']['fy']:.2f} cx {r['intrinsics']['cx']:.2f} "
            f"cy {r['intrinsics']['cy']:.2f}  ({r['intrinsics_source']})")
    if r.get("sizes"):
        lines.append("sizes       " + ", ".join(f"{size} x{n}" for size, n in r["sizes"].items())
                     + "  (mixed; each frame has its own intrinsics)")
    if "points_per_cloud" in r:
        c = r["points_per_cloud"]
        lines.append(f"clouds      {c['min']:,} .. {c['max']:,} points (median {c['median']:,.0f})")
    d = r["depth"]
    if "min_m" in d:
        what = "range" if "points_per_cloud" in r else "depth"
        lines.append(f"{what:<12}{d['min_m']:.3f} .. {d['max_m']:.3f} m  (1-99 %: "
                     f"{d['p01_m']:.3f} .. {d['p99_m']:.3f}, median {d['median_m']:.3f}, "
                     f"valid {100 * d['valid_fraction']:.1f} %)")
    else:
        lines.append("depth       no valid depth")
    if "poses" in r and r["poses"] is None:
        lines.append("poses       none (segmentation dataset)")
    elif "poses" in r:
        p = r["poses"]
        ext = " x ".join(f"{v:.2f}" for v in p["extent_m"])
        lines.append(f"poses       {p['duration_s']:.2f} s, path {p['path_length_m']:.2f} m, "
                     f"extent {ext} m" + (f"  (from {r['pose_source']})"
                                          if r.get("pose_source") else ""))
    if r.get("time_source_reason"):
        lines.append(f"stamps      {r['time_source_reason']}")
    if r.get("dropped"):
        dropped = ", ".join(f"{k.replace('_', ' ')}: {v}" for k, v in r["dropped"].items() if v)
        if dropped:
            lines.append(f"dropped     {dropped}")
    if r.get("ground_truth"):
        lines.append(f"3D truth    {r['ground_truth']} (`evsmap map --json` scores the map "
                     f"against it)")
    if "skipped" in r:
        lines.append("skipped     " + SkippedFrames(
            [(f["index"], f["reason"]) for f in r["skipped"]["frames"]]).summary())
    if r["labels"]:
        lab = r["labels"]
        top = sorted(lab["classes"], key=lambda c: -c["fraction"])
        listed = ", ".join(f"{c['name']} {100 * c['fraction']:.1f}%" for c in top)
        lines.append(f"labels      {lab['classes_present']} classes, void "
                     f"{100 * lab['void_fraction']:.1f} %: {listed}")
    else:
        lines.append("labels      none")
    return "\n".join(lines)
