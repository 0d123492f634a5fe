"""``evsmap predict``: run a segmenter over a sequence and write its prediction for every frame.

Layout of ``--out DIR``::

    DIR/labels/<name>.png     uint8 class ids (the top-1 class), at the frame's resolution
    DIR/overlays/<name>.png   (--overlay) the RGB blended with the class colours, and a legend of
                              the classes present with their pixel shares
    DIR/topk/<name>.npz       (--topk) ``classes`` (uint8; uint16 past 256 classes) and ``probs``
                              (float32), both HxWx3, most likely class first; ``num_classes``
    DIR/predict.json          the summary record (the one ``--json`` prints)

``<name>`` is the frame's own file stem where its reader has one (``Sequence.frame_stem``: TUM the
depth image's timestamp, NYUv2 ``000433``, 7-Scenes ``frame-000042``) and otherwise, or where the
stems of the frames written are not distinct file names, the frame's index (``000000``, six
digits or more).

The network runs at each frame's own resolution unless ``--size HxW`` sets its input size; the
outputs are always at the frame's resolution. Everything is written to a hidden staging folder
beside DIR that replaces DIR once the last frame is done, so an interrupted run leaves no partial
file behind.

Like ``evsmap eval``, a network without ``--weights`` is refused (its random initialisation
predicts noise) unless ``--allow-random`` (:mod:`evsmap.cli.weights_args`); the output folder
follows the commands' output policy (:mod:`evsmap.cli.outputs`).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from pathlib import Path
from typing import Any

from evsmap.cli.options import image_size, key_value, positive_int
from evsmap.cli.outputs import Output, claim_outputs
from evsmap.cli.precision import add_precision_options, apply_precision, backend_for
from evsmap.cli.sequence_args import add_sequence_options, skipped_warning
from evsmap.cli.weights_args import add_weights_options, announce_weights, make_segmenter
from evsmap.errors import EvsmapError

TOPK = 3
"""Classes kept per pixel in ``--topk`` files."""

RECORD_FILE = "predict.json"

_UNSAFE_NAME = re.compile(r"[/\\\x00-\x1f]")



def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "predict", help="run a segmenter over a sequence and write per-frame label images",
        description="Run MODEL over every frame of SEQUENCE (a reader's folder or bag, a "
                    "prepared dataset's name, or 'synthetic') and write DIR/labels/<name>.png "
                    "(uint8 class ids at the frame's resolution; <name> is the frame's own file "
                    "stem, else its index), with --overlay colour overlays and with --topk the "
                    "top-3 classes and probabilities as .npz. A network without --weights is "
                    "refused unless --allow-random.")
    p.add_argument("model", metavar="MODEL", help="segmenter name (evsmap list), e.g. "
                                                  "feagnet-v2 or oracle")
    p.add_argument("sequence", metavar="SEQUENCE",
                   help="a sequence folder or bag, a prepared dataset's name, or 'synthetic'")
    p.add_argument("--out", required=True, type=Path, metavar="DIR",
                   help="output folder (refused when it exists and is not empty, unless "
                        "--overwrite)")
    add_weights_options(p, depends="Its labels")
    p.add_argument("--backend", choices=("torch", "onnxruntime"),
                   help="inference backend of a network segmenter (default torch)")
    p.add_argument("--size", type=image_size, metavar="HxW",
                   help="network input size, e.g. 240x320 (default: each frame's own "
                        "resolution); the outputs are at the frame's resolution either way")
    p.add_argument("--frames", type=positive_int, metavar="N", help="first N frames only")
    p.add_argument("--overlay", action="store_true",
                   help="also write DIR/overlays/<name>.png: the RGB blended with the class "
                        "colours and a legend of the classes present")
    p.add_argument("--topk", action="store_true",
                   help="also write DIR/topk/<name>.npz: the top-3 classes and probabilities "
                        "of every pixel (HxWx3 each)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing non-empty DIR (only once the new one is complete)")
    p.add_argument("-o", "--option", type=key_value, action="append", default=[],
                   metavar="KEY=VALUE",
                   help="a segmenter option, repeatable (e.g. -o dataset=cityscapes, "
                        "-o accuracy=0.9 for the oracle)")
    add_precision_options(p, target="the frames predicted")
    add_sequence_options(p)
    p.add_argument("--json", action="store_true", help="print the summary record as JSON")
    p.set_defaults(run=run)


# -- frame names ------------------------------------------------------------------------------
def index_name(index: int, count: int) -> str:
    """A frame's index as a file name: zero-padded to six digits (more for longer sequences)."""
    return f"{index:0{max(6, len(str(max(count - 1, 0))))}d}"


def frame_names(sequence, count: int) -> tuple[list[str], str]:
    """One output name per frame ``0..count-1`` and how they were made (``"stem"`` or
    ``"index"``): the reader's ``frame_stem(i)`` when it has one and the stems are distinct,
    safe file names; the frame indices otherwise."""
    named = [sequence.frame_stem(i) for i in range(count)]
    if all(s is not None for s in named):
        stems = [str(s) for s in named]
        safe = all(s and s not in (".", "..") and not _UNSAFE_NAME.search(s) for s in stems)
        if safe and len(set(stems)) == len(stems):
            return stems, "stem"
    return [index_name(i, count) for i in range(count)], "index"


# -- pictures ---------------------------------------------------------------------------------
def class_colors(sequence, num_classes: int):
    """``uint8`` (num_classes, 3) display colours: the dataset's own (``meta['class_colors']``,
    e.g. Cityscapes') when it has one per class, else :func:`evsmap.classes.palette`."""
    import numpy as np

    from evsmap.classes import palette

    colors = sequence.meta.get("class_colors")
    if colors is not None and len(colors) == num_classes:
        return np.asarray(colors, dtype=np.uint8).reshape(num_classes, 3)
    return palette(num_classes)


def overlay_image(rgb, labels, colors, names, *, alpha: float = 0.5):
    """``uint8`` HxWx3: ``rgb`` blended with the colour of each pixel's class (void and ids past
    the palette stay as they are), with a legend of the classes present in the top-left corner
    (colour, name, pixel share; the largest first, as many as fit)."""
    import numpy as np
    from PIL import Image, ImageDraw, ImageFont

    n = len(colors)
    known = labels < n
    out = rgb.astype(np.float32)
    lut = np.zeros((256, 3), dtype=np.float32)
    lut[:n] = colors
    out[known] = (1.0 - alpha) * out[known] + alpha * lut[labels[known]]
    image = Image.fromarray(np.clip(np.rint(out), 0, 255).astype(np.uint8)).convert("RGBA")

    counts = np.bincount(labels[known].ravel(), minlength=n)[:n]
    present = [int(c) for c in np.argsort(-counts, kind="stable") if counts[c] > 0]
    if not present:
        return np.asarray(image.convert("RGB"))
    h, w = labels.shape
    try:
        font = ImageFont.load_default(size=max(10, min(h, w) // 32))
    except TypeError:  # Pillow without scalable default font
        font = ImageFont.load_default()
    left, top, right, bottom = font.getbbox("Hg%")
    line = bottom - top + max(2, (bottom - top) // 3)
    pad = max(2, line // 4)
    rows = [f"{names[c] if c < len(names) else c}  {100.0 * counts[c] / known.sum():.1f} %"
            for c in present]
    fit = max(1, (h - 2 * pad) // line)
    if len(rows) > fit:
        rows = rows[:fit - 1] + [f"+{len(rows) - fit + 1} more"] if fit > 1 else rows[:1]
    swatch = line - pad
    width = 3 * pad + swatch + max(int(font.getlength(r)) for r in rows)
    layer = Image.new("RGBA", image.size, (0, 0, 0, 0))
    draw = ImageDraw.Draw(layer)
    draw.rectangle([0, 0, min(width, w - 1), min(2 * pad + line * len(rows), h - 1)],
                   fill=(0, 0, 0, 150))
    for i, text in enumerate(rows):
        y = pad + i * line
        if i < len(present) and not text.startswith("+"):
            color = tuple(int(v) for v in colors[present[i]])
            draw.rectangle([pad, y + 1, pad + swatch - 1, y + swatch], fill=(*color, 255),
                           outline=(255, 255, 255, 255))
        draw.text((2 * pad + swatch, y - top + 1), text, font=font, fill=(255, 255, 255, 255))
    return np.asarray(Image.alpha_composite(image, layer).convert("RGB"))


def _write_png(path: Path, array) -> None:
    from PIL import Image

    Image.fromarray(array).save(path, format="PNG")


# -- the command ------------------------------------------------------------------------------
def _open(args: argparse.Namespace):
    from evsmap.datasets.lookup import find_dataset
    from evsmap.readers.detect import open_sequence

    text, reader = find_dataset(args.sequence, args.reader)
    return open_sequence(text, reader, args.reader_option), text


def run(args: argparse.Namespace) -> int:
    from evsmap.registry import SEGMENTERS

    claim_outputs([Output("--out", args.out, folder=True)], overwrite=args.overwrite)
    config: dict[str, Any] = dict(args.option)
    backend = backend_for(args, args.model)
    if backend is not None:
        config["backend"] = backend
    takes_size = SEGMENTERS.get(args.model).takes.input_size
    if "input_size" in config:
        raise EvsmapError("-o input_size: pass the network input size as --size HxW")
    if args.size is not None:
        if not takes_size:
            raise EvsmapError(f"--size: segmenter {args.model!r} is not a network and has no "
                              f"input size")
        config["input_size"] = args.size
    sequence, source = _open(args)
    if takes_size and args.size is None and sequence.intrinsics is not None:
        config["input_size"] = sequence.intrinsics.shape  # the frames' own resolution
    noise = "its labels are noise"
    segmenter, weights_record = make_segmenter(args, args.model, config,
                                               command="evsmap predict", depends=True,
                                               noise=noise)
    network = segmenter.module is not None
    num_classes = int(segmenter.num_classes)
    if num_classes > 255:
        raise EvsmapError(f"{args.model} predicts {num_classes} classes: the uint8 label images "
                          f"hold at most 255 (255 is void)")
    total = len(sequence) if args.frames is None else min(args.frames, len(sequence))
    if total == 0:
        raise EvsmapError(f"{sequence.name!r} has no frames")
    announce_weights(args, args.model, weights_record, command="evsmap predict",
                     depends=True, noise=noise)
    precision = apply_precision(args, segmenter, sequence, name=args.model, count=total,
                                what="predict")
    from evsmap.environment import describe

    header = {
        "model": args.model,
        "options": {k: (list(v) if isinstance(v, tuple) else v) for k, v in config.items()
                    if k not in ("weights", "input_size")},
        **weights_record,
        "backend": segmenter.backend, **precision,
        "input_size": list(args.size) if args.size is not None else
        ("frame" if network else None),
        "machine": describe()}
    record = predict_sequence(
        sequence, segmenter, args.out, model=args.model, count=total,
        follow_frame_size=network and args.size is None, overlay=args.overlay,
        topk=args.topk, overwrite=args.overwrite, skip_bad=args.skip_bad,
        source=Path(source) if Path(source).exists() else None, header=header)
    if args.json:
        print(json.dumps(record, indent=2))
    else:
        print(format_record(record))
    warning = skipped_warning(record["skipped"], record["frames"])
    if warning:
        sys.stderr.write(f"evsmap predict: warning: {warning}\n")
    return 0


def predict_sequence(sequence, segmenter, out: Path, *, model: str, count: int,
                     follow_frame_size: bool, overlay: bool, topk: bool, overwrite: bool,
                     skip_bad: bool, source: Path | None = None,
                     header: dict[str, Any] | None = None) -> dict[str, Any]:
    """Predict frames ``0..count-1`` of ``sequence`` into the folder ``out`` (staged, then
    renamed into place, with ``predict.json``) and return the summary record: ``header``
    followed by the sequence, frame and file entries."""
    import numpy as np

    from evsmap.classes import class_names_for
    from evsmap.datasets.lookup import dataset_classes
    from evsmap.fileio import staging_folder
    from evsmap.progress import progress
    from evsmap.readers.skipping import SkippedFrames, read_frames

    num_classes = int(segmenter.num_classes)
    _, data_names = dataset_classes(sequence)
    names_of_classes = data_names if len(data_names) == num_classes else \
        tuple(segmenter.class_names or class_names_for(num_classes))
    colors = class_colors(sequence, num_classes) if overlay else None
    names, naming = frame_names(sequence, count)
    skipped = SkippedFrames()
    times_ms: list[float] = []
    pixels = np.zeros(num_classes, dtype=np.int64)
    files: list[dict[str, Any]] = []
    sizes: set[tuple[int, int]] = set()
    class_dtype = np.uint8 if num_classes <= 256 else np.uint16
    with staging_folder(out, overwrite=overwrite, source=source, what="--out ") as stage:
        for sub, wanted in (("labels", True), ("overlays", overlay), ("topk", topk)):
            if wanted:
                (stage / sub).mkdir()
        frames = read_frames(sequence, range(count), skip_bad=skip_bad, skipped=skipped)
        for index, frame in progress(frames, total=count, desc=f"predicting {model}"):
            frame.require_images("evsmap predict")
            shape = (frame.height, frame.width)
            size = segmenter.input_size
            if follow_frame_size and size is not None and tuple(size) != shape:
                segmenter.set_input_size(shape)
            t0 = time.perf_counter()
            try:
                obs = segmenter.predict(frame, k=min(TOPK, num_classes))
            except EvsmapError:
                raise
            except (ValueError, RuntimeError) as exc:
                # a network that cannot take this input size: ESANet's "divisible by 32", a
                # pooling layer's "output size is too small", ...
                if segmenter.input_size is None:
                    raise
                h, w = segmenter.input_size
                why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                raise EvsmapError(f"{model} cannot run at {h}x{w} (frame {frame.name!r}): "
                                  f"{why} (pass another --size HxW)") from None
            times_ms.append((time.perf_counter() - t0) * 1000.0)
            if obs.shape != shape:
                raise EvsmapError(f"{model} returned a {obs.shape[0]}x{obs.shape[1]} prediction "
                                  f"for the {shape[0]}x{shape[1]} frame {frame.name!r}")
            sizes.add(shape)
            labels = obs.argmax.astype(np.uint8)
            pixels += np.bincount(labels.ravel(), minlength=num_classes)[:num_classes]
            name = names[index]
            entry: dict[str, Any] = {"index": int(index), "name": name,
                                     "labels": f"labels/{name}.png"}
            _write_png(stage / entry["labels"], labels)
            if overlay:
                entry["overlay"] = f"overlays/{name}.png"
                _write_png(stage / entry["overlay"],
                           overlay_image(frame.rgb, labels, colors, names_of_classes))
            if topk:
                entry["topk"] = f"topk/{name}.npz"
                np.savez_compressed(stage / entry["topk"],
                                    classes=obs.classes.astype(class_dtype),
                                    probs=obs.probs.astype(np.float32),
                                    num_classes=np.int64(num_classes))
            files.append(entry)
        if not files:
            raise EvsmapError(f"no frame of {sequence.name!r} could be read: "
                              f"{skipped.summary()}")
        total_px = int(pixels.sum())
        seen = {str(names_of_classes[c]): round(int(pixels[c]) / total_px, 6)
                for c in np.argsort(-pixels, kind="stable") if pixels[c] > 0}
        record = {
            **(header or {}),
            "sequence": sequence.name, "frames": len(files), "names": naming,
            "frame_sizes": sorted([h, w] for h, w in sizes),
            "skipped": skipped.as_dict() if skip_bad else None,
            "ms_per_frame_median": float(np.median(times_ms)),
            "ms_per_frame": [round(t, 3) for t in times_ms],
            "num_classes": num_classes, "classes_seen": seen,
            "out": str(Path(out).resolve()), "files": files,
        }
        (stage / RECORD_FILE).write_text(json.dumps(record, indent=2) + "\n")
    return record


def format_record(r: dict[str, Any]) -> str:
    weights = r["weights"] or (f"RANDOM, seed {r['init_seed']}: labels are noise"
                               if r["random_weights"] else "none")
    size = r.get("input_size")
    size = "" if size is None else "; network input: " + \
        ("each frame's resolution" if size == "frame" else f"{size[0]}x{size[1]}")
    naming = "file stems" if r["names"] == "stem" else "frame indices"
    seen = list(r["classes_seen"].items())
    classes = ", ".join(f"{name} {100 * share:.1f} %" for name, share in seen[:6])
    if len(seen) > 6:
        classes += f", and {len(seen) - 6} more"
    written = ["labels"] + [k + "s" if k == "overlay" else k for k in ("overlay", "topk")
                            if k in r["files"][0]]
    lines = [
        f"model      {r['model']}  (weights: {weights}"
        + (f"; int8 {r['int8_scheme']} on {r['instruction_set']}" if r.get("precision") == "int8"
           else "") + ")",
        f"sequence   {r['sequence']}  ({r['frames']} frames, named by {naming})",
        f"time       {r['ms_per_frame_median']:.1f} ms per frame (median{size})",
        f"classes    {classes or 'none'}",
        f"written    {r['out']}  ({', '.join(w + '/' for w in written)}, {RECORD_FILE})",
    ]
    if r.get("skipped"):
        lines.append(f"skipped    {r['skipped']['count']} bad frame(s)")
    return "\n".join(lines)
