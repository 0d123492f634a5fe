"""``--precision fp32|int8`` and its options, shared by ``speed``, ``map``, ``eval`` and
``predict`` (issue 20, int8 inference).

int8 runs on ONNX Runtime only: with ``--precision int8`` the backend defaults to onnxruntime,
and an explicit ``--backend torch`` is refused (exit 2). The network is calibrated on
``--calibration-frames`` frames evenly spaced over the frames the command processes - the
target-data calibration the issue asks for - or, with ``--calibrate-on NAME-or-PATH``, over
another dataset or sequence (held out from what is scored; ``synthetic`` is the built-in
scene). ``speed`` has no sequence and calibrates on the built-in synthetic scene.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from evsmap.cli.options import nonnegative_int, positive_int
from evsmap.devices import DEVICES_HELP, device_name
from evsmap.errors import EvsmapError


def device_arg(text: str) -> str:
    """``--device``'s value, canonical (``cpu``, ``cuda:N``); its spelling checked only (the
    machine is checked when the command runs)."""
    try:
        return device_name(text)
    except EvsmapError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None

PRECISIONS = ("fp32", "fp16", "bf16", "int8")
AUTOCAST_PRECISIONS = ("fp16", "bf16")
SCHEMES = ("auto", "u8s8", "u8s7", "u8u8", "s8s8")
"""``auto`` and evsmap.segmenters.quantize.SCHEMES, spelled out so that building the parser
imports nothing heavy."""
DEFAULT_CALIBRATION_FRAMES = 16


def add_precision_options(p: argparse.ArgumentParser, *, target: str = "the frames processed",
                          calibrate_on: bool = True) -> None:
    """``--precision``, ``--int8-scheme``, ``--calibration-frames``, ``--int8-auto-exclude``
    and (with ``calibrate_on``) ``--calibrate-on``.

    Args:
        p: the command's parser.
        target: what the calibration frames are taken from by default (for the help).
        calibrate_on: offer ``--calibrate-on`` (a command without a sequence does not).
    """
    p.add_argument("--precision", choices=PRECISIONS, default="fp32",
                   help="fp32 (default); fp16 or bf16: torch's autocast at that dtype (torch "
                        "backends; docs/gpu.md); or int8: ONNX Runtime static QDQ "
                        "quantisation, calibrated first (implies --backend onnxruntime; "
                        "docs/int8.md)")
    p.add_argument("--device", type=device_arg, default="cpu", metavar="DEVICE",
                   help=f"where the network runs: {DEVICES_HELP}; a GPU needs a CUDA build "
                        f"of torch (docs/gpu.md)")
    p.add_argument("--int8-scheme", choices=SCHEMES, default="auto",
                   help="int8 types: auto (default: u8s8 where the CPU has VNNI or is ARM, "
                        "u8s7 on x86 without VNNI, whose u8s8 kernels saturate), u8s8 (uint8 "
                        "activations, int8 weights), u8s7 (7-bit weights), u8u8 or s8s8 "
                        "(docs/int8.md, 'Per instruction set')")
    p.add_argument("--calibration-frames", type=positive_int,
                   default=DEFAULT_CALIBRATION_FRAMES, metavar="N",
                   help=f"int8: calibrate on N frames evenly spaced over {target} (default "
                        f"{DEFAULT_CALIBRATION_FRAMES})")
    p.add_argument("--int8-auto-exclude", type=nonnegative_int, default=0, metavar="N",
                   help="int8: also keep in fp32 the nodes around the N tensors with the worst "
                        "quantisation SQNR on the calibration frames (default 0: only the "
                        "rules - final classifier, sigmoid gates, softmax)")
    if calibrate_on:
        p.add_argument("--calibrate-on", metavar="NAME-or-PATH",
                       help="int8: calibrate on this dataset or sequence instead (held-out "
                            "calibration; its train split when it has splits; e.g. "
                            "'synthetic', a prepared dataset's name or a folder)")


def backend_for(args: argparse.Namespace, model: str | None = None) -> str | None:
    """The backend to create the segmenter ``model`` with: ``args.backend``, or onnxruntime
    for int8.

    Raises:
        EvsmapError: ``--precision int8`` with ``--backend torch``, or for a registered
            segmenter that has no backend (not a network: the oracle).
    """
    _check_device(args)
    tensorrt_fp16 = args.precision == "fp16" and getattr(args, "provider", None) == "tensorrt"
    if args.precision in AUTOCAST_PRECISIONS and args.backend == "onnxruntime" \
            and not tensorrt_fp16:
        raise EvsmapError(f"--precision {args.precision} is torch's autocast: pass --backend "
                          f"torch (or leave --backend out)")
    if args.precision != "int8":
        if args.backend is not None and model is not None:
            _require_network(model, f"--backend {args.backend}")
        return args.backend
    if args.backend == "torch":
        raise EvsmapError("--precision int8 runs on ONNX Runtime: pass --backend onnxruntime "
                          "or leave --backend out")
    if model is not None:
        _require_network(model, "--precision int8")
    return "onnxruntime"


def check_device(device: str, precision: str | None) -> None:
    """``--device`` is on this machine and goes with ``--precision`` (before any work; the
    commands with a network and ``reproduce`` alike).

    Raises:
        EvsmapError: a GPU that is not here, or int8 (ONNX Runtime's CPU quantisation) on one.
    """
    if device == "cpu":
        return
    from evsmap.devices import require_device

    require_device(device)
    if precision == "int8":
        raise EvsmapError(f"--precision int8 --device {device}: int8 here is ONNX Runtime's CPU "
                          f"quantisation; on a GPU use --precision fp16 or bf16 (or time int8 "
                          f"on the CPU)")


def _check_device(args: argparse.Namespace) -> None:
    check_device(getattr(args, "device", "cpu"), args.precision)


def _require_network(model: str, option: str) -> None:
    from evsmap.registry import SEGMENTERS

    if not SEGMENTERS.get(model).takes.backend:
        raise EvsmapError(f"{option}: segmenter {model!r} is not a network and has no "
                          f"inference backend (pass --segmenter NAME, a network, or leave "
                          f"{option.split()[0]} out)")


def apply_precision(args: argparse.Namespace, segmenter: Any, sequence: Any, *, name: str,
                    count: int | None = None, what: str = "", place: bool = True
                    ) -> dict[str, Any]:
    """Place ``segmenter`` on ``--device`` at an autocast ``--precision``, or calibrate it to
    int8 when ``--precision int8``; return the record fields (``precision``, ``device`` and
    ``gpu``, the GPU's facts, on a GPU, and for int8 ``int8_scheme`` and ``int8``: how it was
    calibrated).

    Args:
        args: the parsed command line (:func:`add_precision_options`'s options).
        segmenter: the segmenter, created with :func:`backend_for`'s backend.
        name: the name it is registered under (for the error on a segmenter that is not a
            network).
        sequence: the sequence processed (calibration frames come from its first ``count``
            frames), or None where there is none (``--calibrate-on`` or the synthetic scene).
        count: how many of its frames are processed (default all).
        what: the command name for the note on stderr.
        place: move the network to ``--device`` and set an autocast ``--precision`` on it
            (``speed`` times a copy of the module itself and passes neither).

    Raises:
        EvsmapError: int8 for a segmenter that is not a network, or no calibration frame.
    """
    if place and _place(args, segmenter, name):
        from evsmap.environment import collect_gpu

        gpu = collect_gpu(args.device)
        return {**_precision_fields(args, segmenter, sequence, count, what), "gpu": gpu}
    return _precision_fields(args, segmenter, sequence, count, what)


def _precision_fields(args: argparse.Namespace, segmenter: Any, sequence: Any,
                      count: int | None, what: str) -> dict[str, Any]:
    if args.precision != "int8":
        from evsmap.segmenters.network import NetworkSegmenter

        if isinstance(segmenter, NetworkSegmenter):
            return segmenter.precision_record()
        return {"precision": "fp32"} if segmenter.module is not None else {}
    if segmenter.module is None:
        raise EvsmapError(f"--precision int8: {type(segmenter).__name__} is not a network")
    from evsmap.progress import progress
    from evsmap.segmenters.quantize import evenly_spaced

    source_name = getattr(args, "calibrate_on", None)
    if source_name is not None or sequence is None:
        sequence, count, label = _calibration_sequence(source_name or "synthetic")
        if source_name is None:
            label = "the built-in synthetic scene (no sequence to calibrate on)"
    else:
        label = f"{sequence.name} (the frames processed)"
        count = len(sequence) if count is None else min(count, len(sequence))
    indices = evenly_spaced(count, args.calibration_frames)
    frames = [sequence.frame(i) for i in progress(indices, desc="int8 calibration frames")]
    from evsmap.segmenters.quantize import resolve_scheme

    scheme, chosen_by = resolve_scheme(args.int8_scheme)
    if what:
        sys.stderr.write(f"evsmap {what}: int8 ({scheme}, {chosen_by}) calibrated on "
                         f"{len(frames)} frames of {label}\n")
    segmenter.calibrate(frames, scheme=args.int8_scheme, auto_exclude=args.int8_auto_exclude,
                        cache_dir=getattr(args, "cache_dir", None),
                        source=f"{label}: frames {', '.join(map(str, indices))}")
    return segmenter.precision_record()


def _place(args: argparse.Namespace, segmenter: Any, name: str) -> bool:
    """``--device`` and an autocast ``--precision`` applied to a network segmenter (refused in
    one line for a segmenter that is not one); whether it runs on a GPU."""
    device = getattr(args, "device", "cpu")
    autocast = args.precision if args.precision in AUTOCAST_PRECISIONS else None
    _check_device(args)
    if device == "cpu" and autocast is None:
        return False
    from evsmap.segmenters.network import NetworkSegmenter

    if not isinstance(segmenter, NetworkSegmenter):
        option = f"--device {device}" if device != "cpu" else f"--precision {autocast}"
        raise EvsmapError(f"{option}: segmenter {name!r} is "
                          f"not a network (nothing to run on a device or in {autocast or 'it'})")
    segmenter.place(device=device, precision=autocast)
    return device != "cpu"


def _calibration_sequence(name: str) -> tuple[Any, int, str]:
    """The sequence ``--calibrate-on`` names: a dataset with splits gives its ``train`` split
    (held out from the ``test`` split that ``eval`` scores by default)."""
    from evsmap.datasets.lookup import find_dataset, open_dataset, reader_name
    from evsmap.registry import READERS

    text, reader = find_dataset(name, None)
    split = "train" if READERS.get(reader_name(text, reader)).takes.split else None
    sequence, _ = open_dataset(name, reader=None, split=split, limit=None, options=[])
    if len(sequence) == 0:
        raise EvsmapError(f"--calibrate-on {name}: no frames")
    where = f", {split} split" if split else ""
    return sequence, len(sequence), f"{sequence.name}{where} (held out)"
