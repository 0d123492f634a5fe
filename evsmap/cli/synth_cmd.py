"""``evsmap synth``: render a synthetic sequence to disk in the TUM RGB-D layout."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from evsmap.cli.options import nonnegative_int, positive_int
from evsmap.synth.scene import DEFAULT_SCENE, SCENES


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "synth", help="render a synthetic RGB-D sequence (TUM layout + labels)",
        description="Render a procedural indoor room with NYUv2-40 labels to DIR in the TUM RGB-D "
                    "layout: rgb/, depth/ (uint16, metres x 5000), labels/ (uint8, 255 void), "
                    "rgb.txt, depth.txt, labels.txt, groundtruth.txt, intrinsics.txt and "
                    "evsmap.json. Same options, same bytes.")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder")
    p.add_argument("--frames", type=positive_int, default=60, metavar="N",
                   help="number of frames over one lap of the room (default 60)")
    p.add_argument("--seed", type=nonnegative_int, default=0, metavar="S",
                   help="seed of the room layout, camera path and noise (default 0)")
    p.add_argument("--scene", default=DEFAULT_SCENE, metavar="NAME",
                   help=f"room type: {', '.join(sorted(SCENES))} (default {DEFAULT_SCENE})")
    p.add_argument("--width", type=positive_int, default=640, metavar="W",
                   help="image width (default 640)")
    p.add_argument("--height", type=positive_int, default=480, metavar="H",
                   help="image height (default 480)")
    p.add_argument("--noise", action="store_true",
                   help="add Kinect-like depth noise and holes (labels and poses stay exact)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace DIR if it exists (only after the new sequence is complete)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from evsmap.cli.outputs import Output, claim_outputs

    claim_outputs([Output("--out", args.out, folder=True)], overwrite=args.overwrite)
    from evsmap.synth.sequence import SyntheticSequence  # numba and Open3D: only when run
    from evsmap.synth.write import write_synthetic

    seq = SyntheticSequence(scene=args.scene, seed=args.seed, frames=args.frames,
                            width=args.width, height=args.height, noise=args.noise)
    t0 = time.perf_counter()
    write_synthetic(seq, args.out, overwrite=args.overwrite)
    dt = time.perf_counter() - t0
    print(f"wrote {len(seq)} frames ({args.width}x{args.height}, scene {args.scene}, seed "
          f"{args.seed}{', noisy depth' if args.noise else ''}) to {args.out} in {dt:.1f} s",
          file=sys.stdout)
    return 0
