"""``evsmap complexity``: parameters and FLOPs of a segmentation network."""

from __future__ import annotations

import argparse
import json
from typing import Any

from evsmap.cli.options import key_value, positive_int
from evsmap.errors import EvsmapError


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "complexity", help="count a segmentation network's parameters and FLOPs",
        description="Count the parameters and the FLOPs of one forward pass of MODEL with fvcore "
                    "(one multiply-accumulate counts as one flop, as in the paper). Operators "
                    "fvcore cannot count are listed, not dropped.")
    add_model_options(p)
    p.add_argument("--json", action="store_true", help="print the record as JSON")
    p.set_defaults(run=run)


def add_model_options(p: argparse.ArgumentParser) -> None:
    """MODEL, --height, --width and --classes (shared with ``evsmap speed``)."""
    p.add_argument("model", metavar="MODEL", help="registered segmenter (see `evsmap list`)")
    p.add_argument("--height", type=positive_int, metavar="H",
                   help="input height (default: the model's paper resolution)")
    p.add_argument("--width", type=positive_int, metavar="W",
                   help="input width (default: the model's paper resolution)")
    p.add_argument("--classes", type=positive_int, metavar="C",
                   help="number of classes (default: the model's)")
    p.add_argument("-o", "--option", type=key_value, action="append", default=[],
                   metavar="KEY=VALUE",
                   help="a segmenter option, repeatable; e.g. -o cfim=false -o dappf=false for "
                        "a Table III ablation row, -o dataset=cityscapes for a baseline "
                        "(`evsmap list --json` shows each plug-in's options)")


def build_network(args: argparse.Namespace) -> tuple[Any, int, int]:
    """The segmenter named by ``args.model`` and the input size to measure it at."""
    from evsmap.segmenters.create import RANDOM_INIT_SEED, create_segmenter

    config = model_config(args)
    # untrained networks get the same random weights every run: results are repeatable and the
    # ONNX export cache (keyed by the weights) is reused between runs
    segmenter = create_segmenter(args.model, init_seed=RANDOM_INIT_SEED, **config)
    if segmenter.module is None:
        raise EvsmapError(f"segmenter {args.model!r} is not a network; nothing to measure "
                          "(the networks are listed by `evsmap list`)")
    default_h, default_w = segmenter.default_size
    height, width = args.height or default_h, args.width or default_w
    check_input_size(segmenter, args.model, height, width)
    return segmenter, height, width


def model_config(args: argparse.Namespace) -> dict[str, Any]:
    """The segmenter options of ``-o`` and ``--classes`` (the two must agree); the input size
    is ``--height``/``--width``, never ``-o input_size``."""
    config = dict(args.option)
    if args.classes is not None:
        given = config.get("num_classes")
        if given is not None and str(given) != str(args.classes):
            raise EvsmapError(f"--classes {args.classes} and -o num_classes={given} disagree: "
                              "give one of them")
        config["num_classes"] = args.classes
    if "input_size" in config:
        raise EvsmapError(f"-o input_size={config['input_size']} does not set the size measured "
                          "here: pass --height H --width W")
    return config


def check_input_size(segmenter: Any, model: str, height: int, width: int) -> None:
    """One forward pass at ``height`` x ``width``: a size the network cannot take (a pooling
    layer's output shrinking to nothing, a "divisible by 32" check) becomes one clear error."""
    import torch

    try:
        with torch.no_grad():
            segmenter.module.eval()(*segmenter.example_inputs(height, width))
    except (ValueError, RuntimeError) as exc:
        why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise EvsmapError(f"{model} cannot run at {height}x{width}: {why} (pass another "
                          f"--height/--width)") from None


def run(args: argparse.Namespace) -> int:
    segmenter, height, width = build_network(args)
    from evsmap.measure.complexity import measure_complexity

    inputs = segmenter.example_inputs(height, width)
    record = measure_complexity(segmenter.module, inputs)
    result = {"model": args.model, "num_classes": segmenter.num_classes,
              "inputs": list(segmenter.input_names), **record.as_dict()}
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(format_complexity(result))
    return 0


def format_complexity(r: dict[str, Any]) -> str:
    uncounted = ", ".join(f"{op} x{n}" for op, n in r["uncounted_ops"].items()) or "none"
    return "\n".join([
        f"model          {r['model']}  ({r['num_classes']} classes, "
        f"inputs {', '.join(r['inputs'])})",
        f"input          {r['width']}x{r['height']}",
        f"params         {r['params'] / 1e6:.2f} M  ({r['params']:,})",
        f"FLOPs          {r['flops'] / 1e9:.2f} G  (fvcore: 1 MAC = 1 flop)",
        f"conv MACs      {r['conv_macs'] / 1e9:.2f} G",
        f"uncounted ops  {uncounted}",
    ])
