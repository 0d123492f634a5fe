"""The GPU check of issue 41, as one prepared run: every figure the issue's "Done when" asks
for, measured on one GPU through evsmap's own commands, within a time budget.

Run it on a machine with a CUDA build of torch (``benchmarks/gpu_check.sh`` installs evsmap
there first)::

    python benchmarks/gpu_check.py --out DIR [--device cuda] [--budget 540]

Steps, most important first (each a command of its own, with a timeout; a failed step is
recorded and the next one runs; a step that would start past the budget is recorded as
skipped):

1. ``evsmap speed`` of FEAGNet-V2, FEAGNet-V1 and ESANet-R34-NBt1D in fp32 and fp16
   (autocast) on the GPU: CUDA events, a warm-up until the speed settles; the FEAGNet/ESANet
   speed ratios beside the paper's (Table I: 37.7 / 13.4 and 39.2 / 13.4 FPS; the paper's GPU
   is not stated, so the ratio, not the FPS, is what compares);
2. ``evsmap map`` EVSMap end to end (the built-in synthetic room, FEAGNet-V1 on the GPU, the
   multi-class Bayesian update on the CPU, pipelined) and its rate, beside the same on the CPU;
3. ``evsmap train feagnet-v1 --device cuda --amp``: two straight runs of 2 epochs (their
   difference is the GPU's run-to-run floor), 1 epoch + ``--resume`` + 1 (the resume given
   the same ``--amp``/``--deterministic``), and the same with ``--deterministic``, there also
   resumed by ``evsmap train --out DIR --resume`` alone (the settings from its run.json): the
   resumed weights, momentum buffers and AMP scaler against the straight run's, bit for bit;
   ``--channels-last`` beside it (seconds per epoch);
4. ``evsmap speed --backend torch-compile`` beside eager (FEAGNet-V2 fp32);
5. ``evsmap speed --backend onnxruntime`` on the CUDA provider (or its one-line refusal where
   ONNX Runtime is the CPU build);
6. ``evsmap gate --device cuda --update`` into a baseline file of this GPU kind (the networks'
   forward passes);
7. ``torchrun --nproc-per-node 1 -m evsmap train ...`` (the DDP launch path).

Writes ``gpu_check.json`` (every step's command, exit status, seconds and parsed record) and
``gpu_check.md`` (the figures, with the GPU's model) into ``--out``. ``--device cpu --quick``
runs the same plumbing on a CPU with small sizes (what CI-less development can check).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

PAPER_FPS = {"feagnet-v1": 39.2, "feagnet-v2": 37.7, "esanet-r34-nbt1d": 13.4}
"""Table I's FPS (the paper's GPU, not stated; ESANet's "testing on our experiment")."""
NETWORKS = ("feagnet-v2", "esanet-r34-nbt1d", "feagnet-v1")


class Steps:
    """Runs the steps' commands, keeps their records, stops starting new ones at the
    deadline."""

    def __init__(self, out: Path, budget_s: float) -> None:
        self.out, self.deadline = out, time.monotonic() + budget_s
        self.records: dict[str, dict[str, Any]] = {}

    def run(self, name: str, argv: list[str], *, timeout: float, parse_json: bool = True,
            env: dict[str, str] | None = None) -> dict[str, Any] | None:
        left = self.deadline - time.monotonic()
        if left < 10:
            self.records[name] = {"argv": argv, "skipped": "out of time"}
            print(f"[gpu_check] {name}: skipped (out of time)", flush=True)
            return None
        timeout = min(timeout, left)
        print(f"[gpu_check] {name}: {' '.join(argv)}", flush=True)
        t0 = time.monotonic()
        try:
            proc = subprocess.run(argv, capture_output=True, text=True, timeout=timeout,
                                  env={**os.environ, **(env or {})})
            code: int | str = proc.returncode
            stdout, stderr = proc.stdout, proc.stderr
        except subprocess.TimeoutExpired as exc:
            code, stdout, stderr = "timeout", _text(exc.stdout), _text(exc.stderr)
        seconds = time.monotonic() - t0
        record: dict[str, Any] = {"argv": argv, "exit": code, "seconds": round(seconds, 1),
                                  "stderr_tail": stderr.strip().splitlines()[-3:]}
        if code == 0 and parse_json:
            try:
                record["result"] = json.loads(stdout)
            except ValueError:
                record["stdout_tail"] = stdout.strip().splitlines()[-5:]
        elif code != 0:
            record["stdout_tail"] = stdout.strip().splitlines()[-5:]
        self.records[name] = record
        print(f"[gpu_check] {name}: exit {code} after {seconds:.1f} s"
              + ("" if code == 0 else f": {' | '.join(record['stderr_tail'])}"), flush=True)
        self.save()
        return record.get("result") if code == 0 else None

    def save(self) -> None:
        (self.out / "gpu_check.json").write_text(json.dumps(self.records, indent=1,
                                                            default=str))


def _text(data: bytes | str | None) -> str:
    if data is None:
        return ""
    return data.decode(errors="replace") if isinstance(data, bytes) else data


def evsmap(*args: str) -> list[str]:
    return [sys.executable, "-m", "evsmap", *args]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--device", default="cuda")
    p.add_argument("--budget", type=float, default=540.0, help="seconds for all steps")
    p.add_argument("--data", type=Path, default=Path(".gpu-carry"),
                   help="benchmarks/gpu_prepare.sh's folder: tum_fr1_xyz/ (mapped) and train/ "
                        "(trained on); the built-in synthetic room where either is missing "
                        "(it needs Open3D)")
    p.add_argument("--quick", action="store_true",
                   help="small sizes and few passes (the plumbing on a CPU)")
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    steps = Steps(args.out, args.budget)
    work = args.out / "work"
    steps.records["environment"] = environment()
    speed_steps(steps, args)
    map_steps(steps, args)
    train_steps(steps, args, work)
    extra_speed_steps(steps, args)
    gate_step(steps, args)
    ddp_step(steps, args, work)
    steps.save()
    (args.out / "gpu_check.md").write_text(summary(steps.records, args.device))
    print((args.out / "gpu_check.md").read_text())
    return 0


def environment() -> dict[str, Any]:
    import torch

    facts: dict[str, Any] = {"python": sys.version.split()[0], "torch": torch.__version__,
                             "cuda": torch.version.cuda,
                             "cuda_available": torch.cuda.is_available()}
    if torch.cuda.is_available():
        from evsmap.environment import collect_gpu

        facts["gpu"] = collect_gpu(torch.device("cuda:0"))
    try:
        import onnxruntime as ort

        facts["onnxruntime"] = ort.__version__
        facts["ort_providers"] = ort.get_available_providers()
    except ImportError as exc:
        facts["onnxruntime"] = f"not importable: {exc}"
    return facts


def _size(args: argparse.Namespace) -> list[str]:
    return ["--height", "96", "--width", "128"] if args.quick else []


def speed_steps(steps: Steps, args: argparse.Namespace) -> None:
    runs = "5" if args.quick else "100"
    for net in NETWORKS:
        for precision in ("fp32", "fp16"):
            if args.quick and precision == "fp16" and args.device == "cpu":
                precision = "bf16"  # fp16 autocast on a CPU is slow and beside the point
            steps.run(f"speed/{net}/{precision}",
                      evsmap("speed", net, "--device", args.device, "--precision", precision,
                             "--runs", runs, *_size(args), "--json"), timeout=120)


def map_steps(steps: Steps, args: argparse.Namespace) -> None:
    tum = args.data / "tum_fr1_xyz"
    frames = ["--frames", "8"] if args.quick else []
    source = [str(tum), *frames] if tum.is_dir() else \
        ["synthetic", "-r", "frames=8" if args.quick else "frames=60"]
    common = ["map", *source, "--updater", "multiclass-bayes", "--segmenter", "feagnet-v1",
              "--allow-random", "--max-range", "4", "--json"]
    steps.run(f"map/evsmap/{args.device}", evsmap(*common, "--device", args.device),
              timeout=180)
    if args.device != "cpu":
        steps.run("map/evsmap/cpu", evsmap(*common, "--device", "cpu"), timeout=180)


def train_steps(steps: Steps, args: argparse.Namespace, work: Path) -> None:
    prepared = args.data / "train"
    dataset = [str(prepared)] if prepared.is_dir() else ["synthetic", "-r", "frames=8", "-r",
                                                         "width=320", "-r", "height=240"]
    size = ["--crop", "64x96", "--limit", "8"] if args.quick else ["--crop", "240x320"]
    amp = ["--amp"] if args.device != "cpu" else []
    common = ["train", "feagnet-v1", "--dataset", *dataset, *size,
              "--recipe", "synth-proxy", "--epochs", "2", "--batch-size", "4", "--workers",
              "2", "--eval-every", "0", "--device", args.device, *amp, "--json"]
    for flags, tag in (([], "default"), (["--deterministic"], "deterministic")):
        base = work / f"train-{tag}"
        for run in ("straight", "again"):
            steps.run(f"train/{tag}/{run}", evsmap(*common, *flags, "--out",
                                                   str(base / run)), timeout=150)
        # the resume given the flags of the run; with --deterministic also one given none
        resumes = {"resumed": [*amp, *flags, "--device", args.device]}
        if flags:
            resumes["resumed-bare"] = []
        for run, given in resumes.items():
            steps.run(f"train/{tag}/{run}/first-epoch",
                      evsmap(*common, *flags, "--stop-after", "1", "--out", str(base / run)),
                      timeout=150)
            steps.run(f"train/{tag}/{run}/resume", evsmap(
                "train", *given, "--resume", "--out", str(base / run), "--json"), timeout=150)
        steps.records[f"train/{tag}/compare"] = compare_runs(base, ("again", *resumes))
        steps.save()
    steps.run("train/channels-last", evsmap(*common, "--channels-last", "--out",
                                            str(work / "train-cl")), timeout=150)
    steps.records["train/epoch-seconds"] = {
        "default": epoch_seconds(work / "train-default" / "straight"),
        "channels_last": epoch_seconds(work / "train-cl")}


def compare_runs(base: Path, others: tuple[str, ...]) -> dict[str, Any]:
    """The straight run (2 epochs) against each of ``others`` (its repeat, the 1 + resume + 1
    runs): weights equal bit for bit and their largest difference, momentum buffers, AMP
    scaler, and the settings the resumed run recorded."""
    import torch

    from evsmap.train.checkpoint import load_checkpoint

    saved = {}
    for run in ("straight", *others):
        path = base / run / "checkpoint.pt"
        if not path.exists():
            return {"error": f"{path} missing"}
        saved[run] = load_checkpoint(path)

    def diff(a: dict, b: dict) -> dict[str, Any]:
        floats = [k for k in a if a[k].is_floating_point()]
        worst = max(float((a[k].double() - b[k].double()).abs().max()) for k in floats)
        return {"equal": all(torch.equal(a[k], b[k]) for k in a), "max_abs_diff": worst}

    def momentum(ckpt: dict) -> list:
        return [s.get("momentum_buffer") for s in ckpt["optimizer"]["state"].values()]

    straight = saved["straight"]
    out: dict[str, Any] = {}
    for run in others:
        other = saved[run]
        out[run] = {**diff(straight["state_dict"], other["state_dict"]),
                    "epochs": other["epoch"],
                    "momentum_equal": all(torch.equal(a, b) for a, b in zip(
                        momentum(straight), momentum(other), strict=True)),
                    "scaler_equal": straight.get("scaler") == other.get("scaler"),
                    "scaler": other.get("scaler"),
                    "settings": other["run"].get("settings")}
    return out


def epoch_seconds(run: Path) -> list[float] | None:
    path = run / "checkpoint.pt"
    if not path.exists():
        return None
    from evsmap.train.checkpoint import load_checkpoint

    return [round(float(h.get("train_seconds", float("nan"))), 3)
            for h in load_checkpoint(path)["history"]]


def extra_speed_steps(steps: Steps, args: argparse.Namespace) -> None:
    runs = "5" if args.quick else "100"
    net = "feagnet-s" if args.quick else "feagnet-v2"
    steps.run(f"speed/{net}/torch-compile",
              evsmap("speed", net, "--device", args.device, "--backend", "torch-compile",
                     "--runs", runs, *_size(args), "--json"), timeout=300)
    if args.quick:
        steps.run(f"speed/{net}/eager", evsmap("speed", net, "--device", args.device,
                                               "--runs", runs, *_size(args), "--json"),
                  timeout=120)
    steps.run("speed/feagnet-v2/onnxruntime",
              evsmap("speed", "feagnet-v2", "--device", args.device, "--backend",
                     "onnxruntime", "--runs", runs, *_size(args), "--json"), timeout=180)


def gate_step(steps: Steps, args: argparse.Namespace) -> None:
    only = ["net/feagnet-v1/torch", "net/feagnet-v2/torch", "net/esanet-r34-nbt1d/torch"]
    if args.device == "cpu":
        return  # the CPU gate is CI's
    steps.run("gate/update", evsmap("gate", "--device", args.device, "--update", "--baseline",
                                    str(args.out / "gpu_baseline.json"), "--repeats", "1",
                                    "--budget", "2", "--only", *only, "--json"),
              timeout=240)


def ddp_step(steps: Steps, args: argparse.Namespace, work: Path) -> None:
    prepared = args.data / "train"
    dataset = [str(prepared)] if prepared.is_dir() else ["synthetic", "-r", "frames=4"]
    size = ["--crop", "64x96", "--limit", "4"]
    steps.run("train/torchrun", [sys.executable, "-m", "torch.distributed.run", "--standalone",
                                 "--nproc-per-node", "1", "-m", "evsmap", "train",
                                 "feagnet-v1", "--dataset", *dataset, *size, "--recipe",
                                 "synth-proxy", "--epochs", "1",
                                 "--batch-size", "2", "--workers", "0", "--eval-every", "0",
                                 "--device", args.device, "--out", str(work / "ddp"),
                                 "--json"], timeout=120)


# -- the summary -----------------------------------------------------------------------------


def summary(records: dict[str, Any], device: str) -> str:
    env = records.get("environment", {})
    gpu = env.get("gpu", {})
    lines = ["# GPU check (issue 41)", "",
             f"Device {device}: {gpu.get('gpu', 'no GPU')} (CUDA {env.get('cuda')}, driver "
             f"{gpu.get('driver_version', '?')}, SM clock max {gpu.get('clocks_max_sm', '?')} "
             f"MHz), torch {env.get('torch')}, Python {env.get('python')}, ONNX Runtime "
             f"{env.get('onnxruntime')} ({', '.join(env.get('ort_providers', []))}).", "",
             "## Speed (evsmap speed, 480x640 unless --quick, batch 1)", "",
             "| network | precision / backend | FPS median | IQR | ms median | warm-up |",
             "|---|---|---|---|---|---|"]
    fps: dict[tuple[str, str], float] = {}
    for name, rec in records.items():
        if not name.startswith("speed/"):
            continue
        _, net, variant = name.split("/")
        r = rec.get("result")
        if r is None:
            why = rec.get("skipped") or f"exit {rec.get('exit')}: " + " ".join(
                rec.get("stderr_tail", [])[-1:])
            lines.append(f"| {net} | {variant} | not measured: {why} | | | |")
            continue
        fps[(net, variant)] = r["fps_median"]
        settle = r.get("settle") or {}
        warm = (f"{settle.get('passes')} passes, {settle.get('seconds', 0):.1f} s"
                if settle else f"{r['warmup']} passes")
        if r.get("compile_s") is not None:
            warm += f"; compile {r['compile_s']:.1f} s"
        lines.append(f"| {net} | {variant} ({r.get('provider') or r['backend']}) | "
                     f"{r['fps_median']:.1f} | {r['fps_iqr']:.1f} | {r['ms_median']:.2f} | "
                     f"{warm} |")
    lines += ["", "## FEAGNet / ESANet-R34 speed ratio (the same GPU, the same run)", "",
              "| ratio | precision | measured | paper (Table I) |", "|---|---|---|---|"]
    for net in ("feagnet-v2", "feagnet-v1"):
        paper = PAPER_FPS[net] / PAPER_FPS["esanet-r34-nbt1d"]
        for precision in ("fp32", "fp16", "bf16"):
            a, b = fps.get((net, precision)), fps.get(("esanet-r34-nbt1d", precision))
            if a and b:
                lines.append(f"| {net} / esanet-r34-nbt1d | {precision} | {a / b:.2f} | "
                             f"{paper:.2f} ({PAPER_FPS[net]} / 13.4 FPS) |")
    lines += ["", "## EVSMap end to end (evsmap map, TUM fr1_xyz sample or the synthetic room, "
              "FEAGNet-V1 + multiclass-bayes, 5 cm, max range 4 m)", ""]
    for name, rec in records.items():
        if name.startswith("map/"):
            r = rec.get("result")
            if r is None:
                lines.append(f"- {name}: not measured ({rec.get('skipped') or rec.get('exit')})")
                continue
            stages = ", ".join(f"{k} {v:.1f} ms" for k, v in
                               (r.get("stage_ms_median") or {}).items())
            lines.append(f"- {name}: {r.get('frames')} frames, {_rate(r)}; stage medians: "
                         f"{stages}")
    lines += ["", "## Training (evsmap train feagnet-v1, 16 synthetic frames, 2 epochs)", ""]
    for tag in ("default", "deterministic"):
        cmp_ = records.get(f"train/{tag}/compare", {})
        if "error" in cmp_:
            lines.append(f"- {tag}: {cmp_['error']}")
            continue
        for run, r in cmp_.items():
            lines.append(f"- {tag}, straight against {run}: weights equal {r['equal']} (largest "
                         f"difference {r['max_abs_diff']:.3g}), momentum equal "
                         f"{r['momentum_equal']}, AMP scaler equal {r['scaler_equal']}")
    lines.append(f"- seconds per epoch: {records.get('train/epoch-seconds')}")
    ddp = records.get("train/torchrun", {})
    lines.append(f"- torchrun (1 process): exit {ddp.get('exit', ddp.get('skipped'))}")
    gate = records.get("gate/update", {})
    lines += ["", f"## Gate: exit {gate.get('exit', gate.get('skipped'))} "
              f"(gpu_baseline.json holds this GPU kind's figures)", ""]
    return "\n".join(lines) + "\n"


def _rate(r: dict[str, Any]) -> str:
    """The map's rates as :class:`evsmap.measure.mapping.MappingRecord` names them."""
    return (f"wall {r['wall_hz']:.2f} Hz (the whole loop), segment+update "
            f"{r['segment_update_hz']:.2f} Hz, update alone {r['update_hz']:.2f} Hz")


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
