"""``evsmap speed``: inference speed (FPS) of a segmentation network on the CPU or a GPU."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from evsmap.cli.complexity_cmd import add_model_options, check_input_size, model_config
from evsmap.cli.options import nonnegative_int, positive_int
from evsmap.cli.precision import add_precision_options, apply_precision, backend_for
from evsmap.cli.weights_args import add_weights_options, announce_weights, make_segmenter
from evsmap.errors import EvsmapError

# evsmap.measure.speed.BACKENDS and evsmap.models.ort_providers.PROVIDERS, spelled out so that
# building the parser does not import torch
BACKENDS = ("onnxruntime", "torch", "torch-compile")
PROVIDERS = ("cpu", "cuda", "tensorrt")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "speed", help="time a segmentation network on the CPU or a GPU (FPS, roofline)",
        description="Time single forward passes of MODEL on the CPU or a GPU (--device) with "
                    "torch, torch.compile or ONNX Runtime and report the median FPS with its "
                    "inter-quartile range, next to an fp32 matmul roofline of the same device "
                    "measured in the same call. On a GPU: CUDA events around each pass, a "
                    "warm-up until the speed settles, cuDNN autotuning, the GPU's model, "
                    "driver, CUDA and clocks in the record (docs/gpu.md).")
    add_model_options(p)
    add_weights_options(p, depends=None)
    p.add_argument("--backend", choices=BACKENDS,
                   help="torch (eager, inference mode), torch-compile (torch.compile, "
                        "TorchInductor; the first call compiles, its time recorded apart) or "
                        "onnxruntime (cached ONNX export, on --provider); default torch "
                        "(onnxruntime with --precision int8)")
    p.add_argument("--provider", choices=PROVIDERS,
                   help="onnxruntime's execution provider: cpu (default on the CPU), cuda "
                        "(default on a GPU) or tensorrt (fp16 engines with --precision fp16); "
                        "cuda and tensorrt need the evsmap[gpu] extra; implies --backend "
                        "onnxruntime")
    p.add_argument("--runs", type=positive_int, default=20, metavar="N",
                   help="timed forward passes (default 20)")
    p.add_argument("--warmup", type=nonnegative_int, default=3, metavar="N",
                   help="untimed forward passes first (default 3)")
    p.add_argument("--threads", type=positive_int, metavar="N",
                   help="intra-op threads (default: torch's current count)")
    p.add_argument("--cache-dir", type=Path, metavar="DIR",
                   help="ONNX export cache (default $EVSMAP_CACHE_DIR/onnx or "
                        "~/.cache/evsmap/onnx)")
    add_precision_options(p, target="the built-in synthetic scene (this command has no "
                                     "sequence)", calibrate_on=False)
    p.add_argument("--json", action="store_true", help="print the record as JSON")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    backend = backend_for(args) or ("onnxruntime" if args.provider else "torch")
    config = model_config(args)
    segmenter, weights_record = make_segmenter(args, args.model, config, command="evsmap speed",
                                               depends=False)
    if segmenter.module is None:
        raise EvsmapError(f"segmenter {args.model!r} is not a network; nothing to time")
    height = args.height or segmenter.default_size[0]
    width = args.width or segmenter.default_size[1]
    check_input_size(segmenter, args.model, height, width)
    announce_weights(args, args.model, weights_record, command="evsmap speed", depends=False)
    from evsmap.measure.complexity import measure_complexity
    from evsmap.measure.speed import measure_speed

    inputs = segmenter.example_inputs(height, width)
    macs = measure_complexity(segmenter.module, inputs).flops
    int8_path = None
    if args.precision == "int8":
        segmenter.backend, segmenter.input_size = backend, (height, width)
    precision = apply_precision(args, segmenter, None, what="speed", place=False)
    if args.precision == "int8":
        int8_path = segmenter.quantization.path
    autocast = args.precision if args.precision in ("fp16", "bf16") else None
    if autocast:  # speed times a copy of the module under autocast (not the segmenter's own)
        precision = {**precision, "precision": autocast}
    record = measure_speed(
        segmenter.module, inputs, backend=backend, runs=args.runs, warmup=args.warmup,
        threads=args.threads, macs=macs, input_names=segmenter.input_names, key=args.model,
        cache_dir=args.cache_dir, onnx_path=int8_path, device=args.device, autocast=autocast,
        provider=args.provider)
    result = {"model": args.model, "num_classes": segmenter.num_classes,
              "inputs": list(segmenter.input_names), **weights_record, **precision,
              **record.as_dict()}
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(format_speed(result))
    return 0


def format_speed(r: dict[str, Any]) -> str:
    versions = ", ".join(f"{k} {v}" for k, v in r["versions"].items())
    weights = r["weights"] or f"random, seed {r['init_seed']}"
    backend = r["backend"] + (f" on {r['provider']}" if r.get("provider") else "")
    lines = [
        f"model     {r['model']}  ({r['width']}x{r['height']}, backend {backend}, "
        f"{_precision_text(r)}, {r['threads']} thread{'s' if r['threads'] != 1 else ''}, "
        f"weights {weights})",
        f"fps       {r['fps_median']:.2f}  (IQR {r['fps_iqr']:.2f})",
        f"latency   {r['ms_median']:.2f} ms median  (IQR {r['ms_iqr']:.2f} ms; {r['runs']} runs "
        f"after {r['warmup']} warm-up)",
        f"roofline  {100 * r['roofline_fraction']:.1f} % of {r['roofline_gmacs']:.1f} G MAC/s "
        f"fp32 matmul  (achieved {r['achieved_gmacs']:.2f} G MAC/s, "
        f"{r['macs'] / 1e9:.2f} G MAC per frame)",
        f"cpu       {r['cpu']}  ({r['instruction_set']})",
    ]
    if r.get("gpu"):
        lines.append(f"gpu       {gpu_text(r['gpu'])}")
    if r.get("settle"):
        s = r["settle"]
        lines.append(f"warm-up   {s['passes']} passes, {s['seconds']:.1f} s until the speed "
                     f"{'settled' if s['settled'] else 'still drifted (time limit)'}; "
                     f"{r['timer']}")
    if r.get("compile_s") is not None:
        lines.append(f"compile   {r['compile_s']:.1f} s (the first call; not in the timing)")
    lines.append(f"versions  {versions}")
    return "\n".join(lines)


def gpu_text(g: dict[str, Any]) -> str:
    """One line of a GPU record (:func:`evsmap.environment.collect_gpu`)."""
    clocks = (f", SM {g['clocks_sm']}/{g['clocks_max_sm']} MHz" if "clocks_sm" in g else "")
    driver = f", driver {g['driver_version']}" if "driver_version" in g else ""
    return (f"{g['gpu']} (cuda:{g['gpu_index']}, sm {g['compute_capability']}, CUDA "
            f"{g['cuda']}, cuDNN {g['cudnn']}{driver}{clocks}, TF32 matmul "
            f"{'on' if g['tf32_matmul'] else 'off'})")


def _precision_text(r: dict[str, Any]) -> str:
    if r.get("autocast"):
        return f"{r['autocast']} autocast" if r["backend"] != "onnxruntime" \
            else f"{r['autocast']} engines"
    if r.get("precision") != "int8":
        return "fp32"
    return (f"int8 {r['int8_scheme']} ({r['int8_scheme_chosen_by']}), "
            f"{r['int8']['fp32_nodes']} nodes kept fp32")
