"""``evsmap oracle fit|show``: fit the oracle's noise model to a segmenter, and show a profile
(:mod:`evsmap.measure.oracle_fit`, :mod:`evsmap.segmenters.oracle_profile`; docs/oracle.md)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from evsmap.cli.options import key_value, positive_int
from evsmap.cli.sequence_args import add_sequence_options, reader_options
from evsmap.cli.weights_args import add_weights_options, announce_weights, make_segmenter
from evsmap.errors import EvsmapError

COMMAND = "evsmap oracle fit"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("oracle", help="fit the oracle's noise model to a network; show a profile",
                       description="The oracle segmenter stands in for a trained network where "
                                   "weights are missing. `fit` measures how a network errs on "
                                   "labelled frames and fits the oracle's profile to it; "
                                   "`show` prints a profile and its fit's figures.")
    actions = p.add_subparsers(dest="action", required=True, metavar="fit|show")
    f = actions.add_parser(
        "fit", help="fit an oracle profile to a segmenter's errors on labelled frames",
        description="Segment labelled frames with --segmenter, measure how it errs (error "
                    "rates inside regions and at boundaries, per class; which classes it "
                    "confuses; error patches and their persistence from frame to frame; its "
                    "confidence), fit the oracle's settings to those figures and write the "
                    "profile (JSON) to --out; use it with `-s profile=FILE`. Without SEQUENCE: "
                    "three synthetic rooms other than the benchmark's (bedroom, office, kitchen; "
                    "60 frames each, 640x480).")
    f.add_argument("sequence", nargs="?", metavar="SEQUENCE",
                   help="a labelled sequence (a path, or a reader that needs none); default: "
                        "the three synthetic fit rooms")
    add_sequence_options(f)
    f.add_argument("--segmenter", required=True, metavar="NAME",
                   help="the network whose errors the oracle learns (evsmap list)")
    f.add_argument("-s", "--segmenter-option", type=key_value, action="append", default=[],
                   metavar="KEY=VALUE", help="a segmenter option, repeatable")
    add_weights_options(f, depends="the fitted profile would")
    f.add_argument("--out", type=Path, required=True, metavar="FILE",
                   help="the profile to write (JSON; an existing file is replaced only "
                        "once the fit is done)")
    f.add_argument("--name", default=None,
                   help="the profile's name (default: the file's stem)")
    f.add_argument("--frames", type=positive_int, default=None, metavar="N",
                   help="frames per sequence to measure (default: all)")
    f.add_argument("--search-frames", type=positive_int, default=None, metavar="N",
                   help="frames per sequence each candidate of the error-field search draws "
                        "(default 20)")
    f.add_argument("--threads", type=positive_int, default=None, metavar="N",
                   help="the network's intra-op threads (default: all cores)")
    f.add_argument("--json", action="store_true", help="print the profile as JSON")
    f.set_defaults(run=run_fit)
    s = actions.add_parser("show", help="a profile's settings and its fit's figures")
    s.add_argument("profile", nargs="?", default="fitted", metavar="NAME-or-FILE",
                   help="fitted (default), per-pixel, noise-free or a profile file")
    s.add_argument("--json", action="store_true", help="print the profile as JSON")
    s.set_defaults(run=run_show)


def _sequences(args: argparse.Namespace) -> tuple[list[Any], str]:
    from evsmap.measure.oracle_fit import FIT_SCENES, fit_sequences
    from evsmap.readers.detect import open_sequence

    if args.sequence is None:
        if args.reader_option or args.reader:
            raise EvsmapError("--reader / -r need a SEQUENCE (without one the fit reads the "
                              "three synthetic fit rooms)")
        rooms = ", ".join(f"{scene} seed {seed}" for scene, seed in FIT_SCENES)
        return fit_sequences(), f"synthetic rooms ({rooms}; 640x480, depth noise)"
    seq = open_sequence(args.sequence, args.reader, reader_options(args, args.sequence))
    if len(seq) == 0 or seq.frame(0).labels is None:
        raise EvsmapError(f"{args.sequence}: has no ground-truth labels to measure errors "
                          f"against")
    return [seq], seq.name


def run_fit(args: argparse.Namespace) -> int:
    from evsmap.measure.oracle_fit import SEARCH_FRAMES, fit_oracle

    if args.out.is_dir():
        raise EvsmapError(f"--out {args.out}: is a folder; give the profile's file name")
    sequences, frames_from = _sequences(args)
    segmenter, fields = make_segmenter(args, args.segmenter, dict(args.segmenter_option),
                                       command=COMMAND, depends=True,
                                       noise="the fitted profile would describe noise")
    segmenter.set_threads(args.threads)
    announce_weights(args, args.segmenter, fields, command=COMMAND, depends=True)

    def say(line: str) -> None:
        sys.stderr.write(line + "\n")

    about = {"segmenter": args.segmenter, "weights": fields.get("weights"),
             "frames_from": frames_from}
    profile = fit_oracle(segmenter, sequences, about=about, name=args.name or args.out.stem,
                         frames=args.frames, search_frames=args.search_frames or SEARCH_FRAMES,
                         say=say)
    profile.save(args.out)
    if args.json:
        print(json.dumps(profile.to_json(), indent=1))
    else:
        print("\n".join(show_lines(profile)))
        print(f"written: {args.out} (use it with -s profile={args.out})")
    return 0


def run_show(args: argparse.Namespace) -> int:
    from evsmap.segmenters.oracle_profile import load_profile

    profile = load_profile(args.profile)
    if args.json:
        print(json.dumps(profile.to_json(), indent=1))
    else:
        print("\n".join(show_lines(profile)))
    return 0


def _pct(v: float | None) -> str:
    return "-" if v is None else f"{100 * v:.1f} %"


def _num(v: float | None, fmt: str = ".2f") -> str:
    return "-" if v is None else format(v, fmt)


FIGURES = (
    ("interior_error", "error rate, interior", _pct),
    ("band_error", "error rate, boundary band", _pct),
    ("band_errors_in_window", "band errors taking a label within the band", _pct),
    ("interior_errors_touching", "interior errors taking a touching class", _pct),
    ("patch_area", "error patch, area-weighted mean (px at 640 wide)", lambda v: _num(v, ",.0f")),
    ("persistence", "persistence (phi of the same point's errors, consecutive frames)", _num),
    ("true_second", "wrong pixels with the true class second", _pct),
)


def show_lines(profile: Any) -> list[str]:
    """A profile's settings and, when fitted, the segmenter's figures beside the oracle's."""
    p = profile
    out = [f"oracle profile {p.name}: {p.source}",
           f"  accuracy {p.accuracy:.4f} (interior), {p.boundary_accuracy:.4f} within "
           f"{p.boundary_blur} px of a boundary, {len(p.class_accuracy)} classes with their own;"
           f" bleeding across a boundary {p.boundary_across:.2f}",
           f"  confusion {p.confusion}; error field: "
           + (f"squares of {p.error_block} px" if p.error_scale <= 0 and p.world_share <= 0
              else f"scale {p.error_scale:g} px (at 640 wide), world share {p.world_share:g}, "
                   f"world scale {p.world_scale:g} m"),
           "  top-1 probability means: " + ", ".join(f"{k} {v:.2f}"
                                                     for k, v in p.mean_top1.items())
           + f"; concentration {p.concentration:g}; true class second {p.true_second:.2f}"]
    fit = p.fit
    if not fit:
        return out
    net, orc = fit.get("network", {}), fit.get("oracle", {})
    out += ["", f"fit: {fit.get('segmenter')} (weights {fit.get('weights')}) on "
                f"{net.get('frames')} frames of {fit.get('frames_from')}",
            "| figure | network | fitted oracle |", "|---|---:|---:|"]
    for key, label, fmt in FIGURES:
        out.append(f"| {label} | {fmt(net.get(key))} | {fmt(orc.get(key))} |")
    for lag in ("1", "4", "16", "64"):
        a = net.get("autocorrelation", {}).get(lag)
        b = orc.get("autocorrelation", {}).get(lag)
        out.append(f"| error autocorrelation at {lag} px | {_num(a)} | {_num(b)} |")
    for key in ("correct", "wrong"):
        a = net.get("top1_probability", {}).get(key)
        b = orc.get("top1_probability", {}).get(key)
        out.append(f"| mean top-1 probability, {key} | {_num(a)} | {_num(b)} |")
    spread = net.get("class_accuracy_spread", {})
    if spread.get("classes"):
        out.append(f"| per-class interior accuracy, min / median / max ({spread['classes']} "
                   f"classes) | {_pct(spread['min'])} / {_pct(spread['median'])} / "
                   f"{_pct(spread['max'])} | (the same, per class) |")
    return out
