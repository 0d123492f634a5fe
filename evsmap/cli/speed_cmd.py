"""``evsmap speed``: inference speed (FPS) of a segmentation network on the CPU or a GPU."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from evsmap.cli.complexity_cmd import add_model_options, check_input_size, model_config
from evsmap.cli.options import nonnegative_int, positive_float, positive_int
from evsmap.cli.precision import add_precision_options, apply_precision, backend_for
from evsmap.cli.weights_args import add_weights_options, announce_weights, make_segmenter
from evsmap.errors import EvsmapError

# evsmap.measure.speed_backends.BACKENDS and COMPILE_MODES, evsmap.models.ort_providers.PROVIDERS
# and evsmap.measure.batch_sweep's DEFAULT_BATCHES and REFERENCE, spelled out so that building
# the parser does not import torch
BACKENDS = ("onnxruntime", "torch", "torch-compile", "torch-cuda-graph")
COMPILE_MODES = ("default", "reduce-overhead", "max-autotune")
PROVIDERS = ("cpu", "cuda", "tensorrt")
DEFAULT_BATCHES = (1, 2, 4, 8, 16)
REFERENCE = "esanet-r34-nbt1d"
SWEEP_BUDGET_S = 10.0


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
                        "TorchInductor; the first call compiles, its time recorded apart), "
                        "torch-cuda-graph (the pass captured once as a CUDA graph and "
                        "replayed; a GPU only) or onnxruntime (cached ONNX export, on "
                        "--provider); default torch (onnxruntime with --precision int8)")
    p.add_argument("--compile-mode", choices=COMPILE_MODES,
                   help="torch.compile's mode with --backend torch-compile (default: default; "
                        "reduce-overhead replays CUDA graphs on a GPU)")
    p.add_argument("--channels-last", action="store_true",
                   help="the network and its inputs in channels-last memory format (the torch "
                        "backends)")
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
    add_sweep_options(p)
    p.add_argument("--json", action="store_true", help="print the record as JSON")
    p.set_defaults(run=run)


def add_sweep_options(p: argparse.ArgumentParser) -> None:
    """``--batch``, ``--reference``, ``--sweep-backends``, ``--variants`` and ``--budget``."""
    p.add_argument("--batch", type=batch_sizes, metavar="B,B,...",
                   help="a batch sweep: time MODEL and --reference at each batch size (e.g. "
                        f"{','.join(map(str, DEFAULT_BATCHES))}), FPS per image (batch / pass "
                        "time) and the ratio to the reference at each")
    p.add_argument("--reference", metavar="NAME",
                   help=f"the batch sweep's yardstick network (default {REFERENCE}; none: "
                        f"MODEL alone)")
    p.add_argument("--sweep-backends", action="store_true",
                   help="a backend sweep: every way of running MODEL on --device (eager, "
                        "channels-last, CUDA graph, torch.compile's modes, fp16/bf16, ONNX "
                        "Runtime's providers) timed or refused in one line, each one's labels "
                        "against eager fp32's, the fastest that keeps them")
    p.add_argument("--variants", type=comma_list, metavar="PATTERN,...",
                   help="the backend sweep's variants, shell patterns (e.g. 'eager-*,"
                        "cuda-graph-*,*-fp16'; default all; eager-fp32 always runs)")
    p.add_argument("--budget", type=positive_float, default=SWEEP_BUDGET_S, metavar="S",
                   help=f"a sweep's timing rule: seconds of timed passes at most per point "
                        f"(until the median's 95 %% CI is within +-3 %%; default "
                        f"{SWEEP_BUDGET_S:g})")


def batch_sizes(text: str) -> tuple[int, ...]:
    """``1,2,4``: distinct batch sizes >= 1."""
    try:
        sizes = tuple(int(t) for t in text.split(","))
    except ValueError:
        sizes = ()
    if not sizes or min(sizes) < 1 or len(set(sizes)) != len(sizes):
        raise argparse.ArgumentTypeError(f"expected distinct batch sizes >= 1 separated by "
                                         f"commas (e.g. 1,2,4,8,16), got {text!r}")
    return sizes


def comma_list(text: str) -> list[str]:
    items = [t.strip() for t in text.split(",") if t.strip()]
    if not items:
        raise argparse.ArgumentTypeError(f"expected names separated by commas, got {text!r}")
    return items


def check_options(args: argparse.Namespace) -> None:
    """Refuse options that do not go together, before any work (one line each)."""
    if args.compile_mode is not None and args.backend != "torch-compile" \
            and not args.sweep_backends:
        raise EvsmapError(f"--compile-mode {args.compile_mode} is torch.compile's: pass "
                          f"--backend torch-compile")
    if args.batch and args.sweep_backends:
        raise EvsmapError("--batch and --sweep-backends are two sweeps: run one at a time")
    if args.reference is not None and not args.batch:
        raise EvsmapError("--reference is the batch sweep's yardstick: pass --batch B,B,...")
    if args.variants is not None and not args.sweep_backends:
        raise EvsmapError("--variants selects the backend sweep's variants: pass "
                          "--sweep-backends")
    if args.sweep_backends:
        given = [f"--{name.replace('_', '-')}" for name in
                 ("backend", "provider", "compile_mode", "channels_last")
                 if getattr(args, name)] + (
            [f"--precision {args.precision}"] if args.precision != "fp32" else [])
        if given:
            raise EvsmapError(f"{', '.join(given)}: the backend sweep runs every backend and "
                              f"precision itself (select them with --variants PATTERN,...)")
    if args.batch and (args.precision == "int8" or args.backend == "onnxruntime"
                       or args.provider):
        raise EvsmapError("--batch times the torch backends (ONNX Runtime's export and its "
                          "int8 quantisation are made at batch 1): drop --backend onnxruntime, "
                          "--provider and --precision int8")


def run(args: argparse.Namespace) -> int:
    check_options(args)
    if args.batch:
        return run_batch_sweep(args)
    if args.sweep_backends:
        return run_backend_sweep(args)
    backend = backend_for(args) or ("onnxruntime" if args.provider else "torch")
    segmenter, height, width, weights_record = network_to_time(args)
    from evsmap.measure.complexity import measure_complexity
    from evsmap.measure.speed import measure_speed
    from evsmap.measure.speed_backends import make_backend
    from evsmap.measure.timing_policy import RoundsPolicy

    inputs = segmenter.example_inputs(height, width)
    macs = measure_complexity(segmenter.module, inputs).flops
    int8_path = None
    if args.precision == "int8":
        segmenter.backend, segmenter.input_size = backend, (height, width)
    precision = apply_precision(args, segmenter, None, name=args.model, what="speed",
                                place=False)
    if args.precision == "int8":
        int8_path = segmenter.quantization.path
    autocast = args.precision if args.precision in ("fp16", "bf16") else None
    if autocast:  # speed times a copy of the module under autocast (not the segmenter's own)
        precision = {**precision, "precision": autocast}
    onnx = {"input_names": tuple(segmenter.input_names), "key": args.model,
            "cache_dir": args.cache_dir, "onnx_path": int8_path}
    record = measure_speed(
        segmenter.module, inputs,
        backend=make_backend(backend, autocast=autocast, channels_last=args.channels_last,
                             compile_mode=args.compile_mode, provider=args.provider, onnx=onnx),
        policy=RoundsPolicy(runs=args.runs, warmup=args.warmup), threads=args.threads,
        macs=macs, device=args.device)
    result = {"model": args.model, "num_classes": segmenter.num_classes,
              "inputs": list(segmenter.input_names), **weights_record, **precision,
              **record.as_dict()}
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(format_speed(result))
    return 0


def network_to_time(args: argparse.Namespace) -> tuple[Any, int, int, dict[str, Any]]:
    """MODEL with the weights options applied, the size to time it at (checked by one pass) and
    the record's weights fields."""
    segmenter, weights_record = make_segmenter(args, args.model, model_config(args),
                                               command="evsmap speed", depends=False)
    if segmenter.module is None:
        raise EvsmapError(f"segmenter {args.model!r} is not a network; nothing to time")
    height = args.height or segmenter.default_size[0]
    width = args.width or segmenter.default_size[1]
    check_input_size(segmenter, args.model, height, width)
    announce_weights(args, args.model, weights_record, command="evsmap speed", depends=False)
    return segmenter, height, width, weights_record


def reference_network(name: str, seed: int, height: int, width: int) -> Any:
    """The batch sweep's yardstick, its seeded random initialisation (speed does not depend on
    the weights), checked at the size MODEL is timed at."""
    from evsmap.segmenters.create import create_segmenter, is_network

    segmenter = create_segmenter(name, init_seed=seed)
    if not is_network(segmenter):
        raise EvsmapError(f"--reference {name}: not a network; nothing to time")
    check_input_size(segmenter, name, height, width)
    return segmenter


def _sweep_policy(args: argparse.Namespace) -> Any:
    from evsmap.measure.timing_policy import TimingPolicy

    return TimingPolicy(budget_s=args.budget)


def run_batch_sweep(args: argparse.Namespace) -> int:
    segmenter, height, width, weights_record = network_to_time(args)
    from evsmap.measure.batch_sweep import SweepNetwork, batch_sweep
    from evsmap.measure.complexity import measure_complexity
    from evsmap.measure.speed_backends import make_backend

    reference = args.reference or REFERENCE
    segmenters = {args.model: segmenter}
    if reference != "none" and reference != args.model:
        segmenters[reference] = reference_network(reference, args.seed, height, width)
    networks = []
    for name, seg in segmenters.items():
        inputs = seg.example_inputs(height, width)
        networks.append(SweepNetwork(name, seg.module, inputs,
                                     measure_complexity(seg.module, inputs).flops))
    autocast = args.precision if args.precision in ("fp16", "bf16") else None
    sweep = batch_sweep(networks, batches=args.batch,
                        reference=None if reference == "none" else reference,
                        policy=_sweep_policy(args), device=args.device,
                        backend=make_backend(args.backend or "torch", autocast=autocast,
                                             compile_mode=args.compile_mode,
                                             channels_last=args.channels_last),
                        threads=args.threads)
    result = {"model": args.model, "sweep": "batch", "height": height, "width": width,
              "backend": args.backend or "torch", "precision": args.precision,
              "channels_last": args.channels_last, **weights_record, **sweep.as_dict()}
    print(json.dumps(result, indent=2) if args.json else format_batch_sweep(result))
    return 0


def run_backend_sweep(args: argparse.Namespace) -> int:
    segmenter, height, width, weights_record = network_to_time(args)
    from evsmap.measure.backend_sweep import backend_sweep, select_variants
    from evsmap.measure.complexity import measure_complexity

    selected = select_variants(args.variants)
    inputs = segmenter.example_inputs(height, width)
    sweep = backend_sweep(args.model, segmenter.module, inputs, selected=selected,
                          device=args.device, policy=_sweep_policy(args), threads=args.threads,
                          macs=measure_complexity(segmenter.module, inputs).flops,
                          onnx={"input_names": tuple(segmenter.input_names),
                                "cache_dir": args.cache_dir})
    result = {"model": args.model, "sweep": "backends", "height": height, "width": width,
              **weights_record, **sweep.as_dict()}
    print(json.dumps(result, indent=2) if args.json else format_backend_sweep(result))
    return 0


def format_batch_sweep(r: dict[str, Any]) -> str:
    ref = r["reference"]
    lines = [f"batch sweep  {r['width']}x{r['height']}, backend {r['backend']}, "
             f"{r['precision']}{', channels-last' if r['channels_last'] else ''}, "
             f"{r['device']}; FPS per image = batch / pass time"
             + (f"; ratio to {ref} at each batch" if ref else ""),
             f"{'network':<22} {'batch':>5} {'pass ms':>10} {'FPS/image':>10} "
             f"{'ratio':>7}"]
    for p in r["points"]:
        if p["refused"]:
            lines.append(f"{p['network']:<22} {p['batch']:>5}  {p['refused']}")
            continue
        ratio = f"{p['ratio_to_reference']:.2f}" if p["ratio_to_reference"] else "-"
        lines.append(f"{p['network']:<22} {p['batch']:>5} {p['ms_median']:>10.2f} "
                     f"{p['fps_per_image']:>10.1f} {ratio:>7}")
    return "\n".join(lines)


def format_backend_sweep(r: dict[str, Any]) -> str:
    lines = [f"backend sweep  {r['network']} {r['width']}x{r['height']} on {r['device']}; "
             f"labels against {r['reference']}'s: fp32 variants must equal them, fp16/bf16 keep "
             f">= {100 * r['reduced_precision_agreement']:g} % of pixels",
             f"{'variant':<30} {'pass ms':>9} {'speed-up':>8}  {'labels':<16} {'bound':<7} "
             f"compile"]
    for v in r["results"]:
        if v["status"] != "timed":
            lines.append(f"{v['variant']:<30} {v['status']}: {v['why']}")
            continue
        compile_s = f"{v['compile_s']:.1f} s" if v["compile_s"] is not None else ""
        lines.append(f"{v['variant']:<30} {v['ms_median']:>9.2f} {v['speedup']:>7.2f}x  "
                     f"{_labels_text(v):<16} {v['bound'] or '':<7} {compile_s}")
    best = next((v for v in r["results"] if v["variant"] == r["fastest"]), None)
    if best is not None:
        lines.append(f"fastest with eager fp32's labels: {best['variant']} "
                     f"({best['ms_median']:.2f} ms, {best['speedup']:.2f}x eager fp32)")
    return "\n".join(lines)


def _labels_text(v: dict[str, Any]) -> str:
    share = v["label_agreement"]
    text = "equal" if share == 1.0 else f"{100 * share:.3f} %"
    return text + ("" if v["qualifies"] else " (fails)")


def format_speed(r: dict[str, Any]) -> str:
    versions = ", ".join(f"{k} {v}" for k, v in r["versions"].items())
    weights = r["weights"] or f"random, seed {r['init_seed']}"
    backend = r["backend"] + (f" on {r['provider']}" if r.get("provider") else "") + (
        f" ({r['compile_mode']})" if r.get("compile_mode") else "") + (
        ", channels-last" if r.get("channels_last") else "")
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
    if (r.get("busy") or {}).get("busy_share") is not None:
        lines.append(_busy_text(r))
    lines.append(f"versions  {versions}")
    return "\n".join(lines)


def _busy_text(r: dict[str, Any]) -> str:
    """Where a GPU pass's time goes: kernels, the host's dispatch, the bound."""
    b = r["busy"]
    dispatch = f", host dispatch {r['dispatch_ms']:.2f} ms" if r.get("dispatch_ms") else ""
    return (f"busy      GPU busy {100 * b['busy_share']:.0f} % of the pass ({b['kernel_ms']:.2f} "
            f"ms of kernels{dispatch}): {b['bound']}-bound")


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
