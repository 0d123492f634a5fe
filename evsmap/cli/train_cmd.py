"""``evsmap train``: train a registered network on a labelled dataset with a recipe (the paper's
by default), one process or DDP under ``torchrun``.

``torchrun --nproc-per-node N -m evsmap train MODEL ...`` runs N processes (gloo on the CPU,
nccl on CUDA); the recipe's batch is split over them and only rank 0 writes. See
``docs/training.md`` and :mod:`evsmap.train.loop`. Nothing here imports torch until the command
runs.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from evsmap.cli.options import key_value, nonnegative_int, positive_float, positive_int


def _size(text: str) -> str:
    from evsmap.train.recipe import parse_size

    try:
        h, w = parse_size(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return f"{h}x{w}"



def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "train", help="train a network on a labelled dataset (the paper's recipe by default)",
        description="Train MODEL on the training split of a labelled dataset with a recipe "
                    "(default: paper, EVSMaP section IV: SGD, lr 0.005, batch 8, 500 epochs, "
                    "poly schedule from epoch 150, random scale/crop/flip, Dice + soft CE on "
                    "every output head), validating on the split `evsmap eval` scores. Every "
                    "epoch writes OUT/checkpoint.pt (resume point), OUT/last.pt and OUT/best.pt "
                    "(weights with a card, for --weights), OUT/log.csv and OUT/run.json. Under "
                    "`torchrun --nproc-per-node N -m evsmap train ...` the run is distributed "
                    "(DDP). --epochs, --batch-size, --lr, --crop, --workers, --amp, "
                    "--eval-every, --seed and --set each override one recipe field.")
    p.add_argument("model", metavar="MODEL", nargs="?", default="",
                   help="segmenter name (evsmap list); resuming: the run's")
    p.add_argument("--dataset", default="", metavar="NAME-or-PATH",
                   help="labelled dataset: a folder, a prepared dataset's name, or a reader "
                        "that needs no path (required, but when resuming: the run's)")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="the run's folder")
    p.add_argument("--recipe", metavar="NAME-or-FILE",
                   help="a shipped recipe (paper, synth-proxy) or a TOML file (default: paper; "
                        "resuming: the checkpoint's)")
    _add_recipe_fields(p)
    p.add_argument("--device", metavar="cpu|cuda",
                   help="cpu, cuda or cuda:N (default: cuda when available; under torchrun "
                        "each process takes cuda:LOCAL_RANK)")
    p.add_argument("--channels-last", action="store_true",
                   help="the network and its inputs in channels-last memory format (NHWC: "
                        "tensor-core convolutions on a GPU; docs/gpu.md)")
    p.add_argument("--deterministic", action="store_true",
                   help="deterministic algorithms only (cuDNN's autotuner off; torch warns of "
                        "an operation without a deterministic kernel): a resumed run repeats a "
                        "straight one bit for bit on a GPU as on the CPU")
    p.add_argument("--threads", type=positive_int, metavar="N",
                   help="torch's intra-op threads for the whole run (default: torch's count, "
                        "recorded in run.json; the weights depend on it)")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in --out from its checkpoint (weights, optimizer, "
                        "schedule, AMP scaler, random states) with the settings recorded in "
                        "its run.json: `evsmap train --out DIR --resume` needs no other flag, "
                        "and a flag that conflicts with the run is refused")
    p.add_argument("--stop-after", type=positive_int, metavar="N",
                   help="stop after N epochs of this invocation (continue with --resume)")
    p.add_argument("--init", type=Path, metavar="FILE",
                   help="encoder weights to start from (an ImageNet backbone or another "
                        "network's state dict); prints what was and was not loaded")
    p.add_argument("-o", "--option", type=key_value, action="append", default=[],
                   metavar="KEY=VALUE",
                   help="a segmenter option, repeatable (e.g. -o num_classes=37)")
    p.add_argument("--train-split", metavar="SPLIT", help="training split (default: train)")
    p.add_argument("--val-split", metavar="SPLIT",
                   help="validation split (default: what evsmap eval scores: test; val for "
                        "cityscapes)")
    p.add_argument("--limit", type=positive_int, metavar="N",
                   help="first N frames of each split only")
    p.add_argument("--reader", metavar="NAME",
                   help="use this reader instead of detecting one from the path (evsmap list)")
    p.add_argument("-r", "--reader-option", type=key_value, action="append", default=[],
                   metavar="KEY=VALUE", help="a reader option, repeatable")
    p.add_argument("--json", action="store_true",
                   help="print the summary as JSON (the per-epoch lines go to stderr)")
    p.set_defaults(run=run)


def _add_recipe_fields(p: argparse.ArgumentParser) -> None:
    """The flags that each override one recipe field."""
    p.add_argument("--epochs", type=positive_int, metavar="N", help="recipe field epochs")
    p.add_argument("--batch-size", type=positive_int, metavar="N",
                   help="recipe field batch_size (global: split over DDP processes)")
    p.add_argument("--lr", type=positive_float, metavar="LR", help="recipe field lr")
    p.add_argument("--crop", type=_size, metavar="HxW", help="recipe field crop")
    p.add_argument("--workers", type=nonnegative_int, metavar="N",
                   help="recipe field workers (data-loading processes per training process)")
    p.add_argument("--amp", action=argparse.BooleanOptionalAction, default=None,
                   help="recipe field amp: float16 autocast + GradScaler (CUDA only)")
    p.add_argument("--eval-every", type=nonnegative_int, metavar="N",
                   help="recipe field eval_every: validate every N epochs and after the last "
                        "(0: never)")
    p.add_argument("--seed", type=nonnegative_int, metavar="S", help="recipe field seed")
    p.add_argument("--set", dest="fields", type=key_value, action="append", default=[],
                   metavar="FIELD=VALUE",
                   help="any recipe field, repeatable (e.g. --set poly_start_epoch=0, "
                        "--set scale=0.5,2.0)")


def overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The recipe fields the command line sets (flags, then --set)."""
    out: dict[str, Any] = {}
    for flag, key in (("epochs", "epochs"), ("batch_size", "batch_size"), ("lr", "lr"),
                      ("crop", "crop"), ("workers", "workers"), ("amp", "amp"),
                      ("eval_every", "eval_every"), ("seed", "seed")):
        value = getattr(args, flag)
        if value is not None:
            out[key] = value
    for key, value in args.fields:
        out[key] = value
    return out


def check_out(out: Path) -> None:
    """The run's folder checked before anything is loaded: not a file, and a place this process
    can write in (a run continues or resumes in an existing folder, so that is not refused here:
    whether it already holds a run is :func:`evsmap.train.setup.open_run_folder`'s check).

    Raises:
        EvsmapError: one line naming --out.
    """
    from evsmap.cli.outputs import Output, claim_outputs

    claim_outputs([Output("--out", out, folder=True, in_place=True)], overwrite=False)


def run(args: argparse.Namespace) -> int:
    import os
    import sys

    from evsmap.interrupt import set_resume_hint

    check_out(args.out)

    def hint() -> str:
        from evsmap.train.checkpoint import CHECKPOINT

        if (args.out / CHECKPOINT).is_file():
            return (f"the last finished epoch is in {args.out / CHECKPOINT}: continue from it "
                    f"with `evsmap train --out {args.out} --resume`")
        return f"no epoch had finished; run the same command again (nothing in {args.out} " \
               f"is half-written)"

    set_resume_hint(hint)  # before the imports below, which take seconds
    from evsmap.train.loop import train
    from evsmap.train.options import RunOptions

    opts = RunOptions(
        model=args.model, dataset=args.dataset, out=args.out, recipe=args.recipe,
        overrides=overrides(args), options=dict(args.option), reader=args.reader,
        reader_options=list(args.reader_option), train_split=args.train_split,
        val_split=args.val_split, limit=args.limit, device=args.device,
        channels_last=args.channels_last, deterministic=args.deterministic, threads=args.threads,
        resume=args.resume, init=args.init, stop_after=args.stop_after,
        messages=sys.stderr if args.json else sys.stdout)
    summary = train(opts)
    if int(os.environ.get("RANK", "0")) != 0:
        return 0
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    best = summary["best_val_miou"]
    state = "finished" if summary["finished"] else "stopped"
    print(f"{state} after {summary['epochs']} of {summary['epochs_planned']} epochs"
          + (f"; best val mIoU {100 * best:.2f} % (epoch {summary['best_epoch']})"
             if best is not None else ""))
    for name, path in summary["files"].items():
        print(f"  {name:<14} {path}")
    if "best.pt" in summary["files"]:
        options = {k: v for k, v in summary["options"].items() if k != "weights"}
        print(f"evaluate with: evsmap eval {summary['model']} --weights "
              f"{summary['files']['best.pt']} --dataset {summary['dataset']}"
              + "".join(f" -o {k}={v}" for k, v in options.items()))
    return 0
