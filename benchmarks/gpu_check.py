"""The GPU check of issue 53, as one prepared run sized for a lent GPU: at most 8 minutes
(``--budget 480``), the most important figures first, every step a command of its own with a
budget of its own (its timeout) so that a slow step cannot starve the rest.

Run it on a machine with a CUDA build of torch (``benchmarks/gpu_check.sh`` installs evsmap
there first)::

    python benchmarks/gpu_check.py --out DIR [--device cuda] [--budget 480]

Steps, most important first (a failed or timed-out step is recorded and the next one runs; a
step that would start past the overall budget is recorded as skipped):

a. **timer agreement**: ``evsmap speed`` and the gate (``evsmap gate --device cuda``) time
   FEAGNet-V2 and ESANet-R34-NBt1D at 480x640, batch 1, at the same host threads (1, the
   gate's); their medians side by side (the goal: within 5 %);
b. **the backend sweep** (``evsmap speed --sweep-backends``) of FEAGNet-V2, FEAGNet-V1 and
   ESANet: eager, CUDA graph (also channels-last) and, for V2, torch.compile's reduce-overhead,
   at fp32/fp16/bf16, each one's labels against eager fp32's, the fastest that keeps them; the
   FEAGNet/ESANet ratios eager and with CUDA graphs beside the paper's 2.81 / 2.93; ONNX
   Runtime's CUDA and TensorRT providers (or their one-line refusals);
c. **the batch sweep** (``evsmap speed --batch 1,2,4,8,16``) of FEAGNet-V2 and V1 against
   ESANet: FPS per image and the ratio at each batch;
d. **EVSMap end to end**: ``evsmap map`` on the TUM sample with FEAGNet-V2 on the GPU (the goal:
   >= 30 Hz), the stages' medians and shares, and whatever else map's ``--json`` prints (its
   thread plan);
e. **the resume proof** (determinism): ``evsmap train feagnet-v1 --deterministic`` 2 epochs
   straight against 1 epoch + ``--resume`` + 1: weights, momentum and AMP scaler bit for bit;
f. **the gate's GPU kind**: ``evsmap gate --device cuda --update`` of the three networks into
   ``gpu_baseline.json``.

Writes ``gpu_check.json`` (every step's command, exit status, seconds and parsed record) and
``gpu_check.md`` (one table of the figures, headed by the GPU's model and clocks) into
``--out``. ``--device cpu --quick`` runs the same plumbing on a CPU at small sizes in about a
minute and a half (FEAGNet-S for the timer agreement, since the gate times 480x640).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

PAPER_FPS = {"feagnet-v1": 39.2, "feagnet-v2": 37.7, "esanet-r34-nbt1d": 13.4}
"""Table I's FPS (the paper's GPU, not stated; ESANet's "testing on our experiment")."""
REFERENCE = "esanet-r34-nbt1d"
AGREEMENT_GOAL = 0.05
"""``speed`` and the gate within 5 % of each other (issue 53)."""
MAP_GOAL_HZ = 30.0
BUDGET_S = 480.0
STEP_TIMEOUTS = {"speed": 75, "gate-pair": 120, "sweep-v2": 150, "sweep": 75, "batch": 75,
                 "map": 90, "train": 60, "gate-kind": 100}
"""Each step's own budget, seconds (on an H200: speed ~20 s, a sweep ~40 s without
torch.compile and ~60 s more with it, a batch sweep ~45 s, the map ~25 s, a training run
~20 s, the gate ~15 s a network)."""
SWEEP_VARIANTS = "eager-*,cuda-graph-fp32,cuda-graph-fp16,cuda-graph-bf16"
"""The backend sweep of every network: eager and the CUDA graph at each precision."""
SWEEP_V2_EXTRA = ("channels-last-fp16,cuda-graph-channels-last-fp16,"
                  "compile-reduce-overhead-fp32,onnxruntime-cuda-fp32,onnxruntime-tensorrt-fp16")
"""FEAGNet-V2's sweep beside them: channels-last (tensor cores), torch.compile with CUDA graphs
(one compile: about a minute), ONNX Runtime's GPU providers (refused in one line where the
image has ONNX Runtime's CPU build)."""
QUICK_VARIANTS = "eager-bf16,cuda-graph-fp32"
"""--quick's sweep (eager fp32 always runs): bf16 (fp16 autocast on a CPU is ten times slower
than fp32 and beside the point) and one GPU-only variant's refusal."""


class Steps:
    """Runs the steps' commands, keeps their records, stops starting new ones at the
    deadline."""

    def __init__(self, out: Path, budget_s: float) -> None:
        self.out, self.deadline = out, time.monotonic() + budget_s
        self.records: dict[str, dict[str, Any]] = {}

    def run(self, name: str, argv: list[str], *, timeout: float,
            env: dict[str, str] | None = None) -> dict[str, Any] | None:
        left = self.deadline - time.monotonic()
        if left < 10:
            self.records[name] = {"argv": argv, "skipped": "out of time"}
            print(f"[gpu_check] {name}: skipped (out of time)", flush=True)
            return None
        timeout = min(timeout, left)
        print(f"[gpu_check] {name} (at most {timeout:.0f} s): {' '.join(argv)}", flush=True)
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
        try:
            record["result"] = json.loads(stdout) if stdout.strip() else None
        except ValueError:
            record["stdout_tail"] = stdout.strip().splitlines()[-5:]
        self.records[name] = record
        print(f"[gpu_check] {name}: exit {code} after {seconds:.1f} s"
              + ("" if code == 0 else f": {' | '.join(record['stderr_tail'])}"), flush=True)
        self.save()
        return record.get("result") if code in (0, 1) else None  # the gate exits 1 on a FAIL

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
    p.add_argument("--budget", type=float, default=BUDGET_S,
                   help=f"seconds for all steps (default {BUDGET_S:g}: 8 minutes)")
    p.add_argument("--data", type=Path, default=Path(".gpu-carry"),
                   help="benchmarks/gpu_prepare.sh's folder: tum_fr1_xyz/ (mapped) and train/ "
                        "(trained on); the built-in synthetic room where either is missing "
                        "(it needs Open3D)")
    p.add_argument("--quick", action="store_true",
                   help="small sizes and few passes (the plumbing on a CPU)")
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    steps = Steps(args.out, args.budget)
    steps.records["environment"] = environment()
    for step in (timer_agreement, backend_sweeps, batch_sweeps, end_to_end, resume_proof,
                 gate_kind):
        step(steps, args)
    steps.save()
    (args.out / "gpu_check.md").write_text(summary(steps.records, args))
    print((args.out / "gpu_check.md").read_text())
    return 0


def environment() -> dict[str, Any]:
    import torch

    facts: dict[str, Any] = {"python": sys.version.split()[0], "torch": torch.__version__,
                             "cuda": torch.version.cuda,
                             "cuda_available": torch.cuda.is_available(),
                             "host_cpus": len(os.sched_getaffinity(0))
                             if hasattr(os, "sched_getaffinity") else os.cpu_count()}
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


# -- the steps --------------------------------------------------------------------------------


def _size(args: argparse.Namespace) -> list[str]:
    return ["--height", "64", "--width", "96"] if args.quick else []


def _agreement_networks(args: argparse.Namespace) -> tuple[str, ...]:
    """The networks timed by both timers: at 480x640 (the gate's size) even with --quick, so
    on a CPU the small FEAGNet-S alone."""
    return ("feagnet-s",) if args.quick and args.device == "cpu" else ("feagnet-v2", REFERENCE)


def timer_agreement(steps: Steps, args: argparse.Namespace) -> None:
    nets = _agreement_networks(args)
    runs = "10" if args.quick else "100"
    for net in nets:
        steps.run(f"a/speed/{net}", evsmap("speed", net, "--device", args.device, "--threads",
                                           "1", "--runs", runs, "--height", "480", "--width",
                                           "640", "--json"),
                  timeout=STEP_TIMEOUTS["speed"])
    steps.run("a/gate", evsmap("gate", "--device", args.device, "--threads", "1", "--update",
                               "--baseline", str(args.out / "gpu_pair_baseline.json"),
                               "--repeats", "1", "--budget", "1" if args.quick else "2",
                               "--confirm", "0", "--only",
                               *(f"net/{n}/torch" for n in nets), "--json"),
              timeout=STEP_TIMEOUTS["gate-pair"])


def _sweep_networks(args: argparse.Namespace) -> tuple[str, ...]:
    if args.quick and args.device == "cpu":
        return ("feagnet-s", REFERENCE)
    return ("feagnet-v2", "feagnet-v1", REFERENCE)


def backend_sweeps(steps: Steps, args: argparse.Namespace) -> None:
    for i, net in enumerate(_sweep_networks(args)):
        first = i == 0
        variants = QUICK_VARIANTS if args.quick else \
            SWEEP_VARIANTS + ("," + SWEEP_V2_EXTRA if first else "")
        steps.run(f"b/sweep/{net}", evsmap(
            "speed", net, "--device", args.device, "--sweep-backends", "--variants", variants,
            "--budget", "0.3" if args.quick else "1", *_size(args), "--json"),
            timeout=STEP_TIMEOUTS["sweep-v2" if first else "sweep"])


def batch_sweeps(steps: Steps, args: argparse.Namespace) -> None:
    batches = "1,2" if args.quick else "1,2,4,8,16"
    nets = _sweep_networks(args)[:-1]  # each against ESANet, timed in the same process
    for net in nets:
        steps.run(f"c/batch/{net}", evsmap(
            "speed", net, "--device", args.device, "--batch", batches, "--reference",
            REFERENCE, "--budget", "0.3" if args.quick else "0.5", *_size(args), "--json"),
            timeout=STEP_TIMEOUTS["batch"])


def end_to_end(steps: Steps, args: argparse.Namespace) -> None:
    tum = args.data / "tum_fr1_xyz"
    frames = ["--frames", "8" if args.quick else "300"]
    source = [str(tum), *frames] if tum.is_dir() else \
        ["synthetic", "-r", "frames=8", "-r", "width=160", "-r", "height=120"] if args.quick \
        else ["synthetic", "-r", "frames=60"]
    steps.run(f"d/map/{args.device}", evsmap(
        "map", *source, "--updater", "multiclass-bayes", "--segmenter",
        "feagnet-s" if args.quick and args.device == "cpu" else "feagnet-v2", "--allow-random",
        "--max-range", "4", "--device", args.device, "--json"), timeout=STEP_TIMEOUTS["map"])


def resume_proof(steps: Steps, args: argparse.Namespace) -> None:
    prepared = args.data / "train"
    dataset = [str(prepared)] if prepared.is_dir() else ["synthetic", "-r", "frames=8", "-r",
                                                         "width=320", "-r", "height=240"]
    size = ["--crop", "64x96", "--limit", "8"] if args.quick else ["--crop", "240x320"]
    amp = ["--amp"] if args.device != "cpu" else []
    common = ["train", "feagnet-v1", "--dataset", *dataset, *size, "--recipe", "synth-proxy",
              "--epochs", "2", "--batch-size", "4", "--workers", "2", "--eval-every", "0",
              "--device", args.device, *amp, "--deterministic", "--json"]
    base = args.out / "work" / "train-deterministic"
    timeout = STEP_TIMEOUTS["train"]
    steps.run("e/train/straight", evsmap(*common, "--out", str(base / "straight")),
              timeout=timeout)
    steps.run("e/train/first-epoch", evsmap(*common, "--stop-after", "1", "--out",
                                            str(base / "resumed")), timeout=timeout)
    steps.run("e/train/resume", evsmap("train", *amp, "--deterministic", "--device",
                                       args.device, "--resume", "--out", str(base / "resumed"),
                                       "--json"), timeout=timeout)
    steps.records["e/train/compare"] = compare_runs(base, ("resumed",))
    steps.save()


def gate_kind(steps: Steps, args: argparse.Namespace) -> None:
    nets = ("feagnet-s",) if args.quick and args.device == "cpu" else \
        ("feagnet-v1", "feagnet-v2", REFERENCE)
    steps.run("f/gate-update", evsmap(
        "gate", "--device", args.device, "--update", "--baseline",
        str(args.out / "gpu_baseline.json"), "--repeats", "1", "--budget", "2", "--only",
        *(f"net/{n}/torch" for n in nets), "--json"), timeout=STEP_TIMEOUTS["gate-kind"])


def compare_runs(base: Path, others: tuple[str, ...]) -> dict[str, Any]:
    """The straight run (2 epochs) against each of ``others`` (the 1 + resume + 1 runs):
    weights equal bit for bit and their largest difference, momentum buffers, AMP scaler, and
    the settings the resumed run recorded."""
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
                    "settings": other["run"].get("settings")}
    return out


# -- the summary: one table -------------------------------------------------------------------


@dataclass(frozen=True)
class Row:
    step: str
    what: str
    measured: str
    beside: str = ""


def summary(records: dict[str, Any], args: argparse.Namespace) -> str:
    env = records.get("environment", {})
    rows = [*agreement_rows(records), *sweep_rows(records), *ratio_rows(records),
            *batch_rows(records), *map_rows(records), *resume_rows(records),
            *gate_rows(records)]
    lines = ["# GPU check (issue 53)", "", header(env, args.device, _gpu_under_load(records)),
             "",
             "| step | what | measured | beside |", "|---|---|---|---|"]
    lines += [f"| {r.step} | {r.what} | {r.measured} | {r.beside} |" for r in rows]
    return "\n".join(lines) + "\n"


def _gpu_under_load(records: dict[str, Any]) -> dict[str, Any]:
    """The GPU's facts as the first speed record read them after its timed passes (the clocks
    under load), else as read at the start."""
    for name in records:
        result = _result(records, name) if name.startswith("a/speed/") else None
        if result and result.get("gpu"):
            return dict(result["gpu"])
    return dict(records.get("environment", {}).get("gpu", {}))


def header(env: dict[str, Any], device: str, gpu: dict[str, Any]) -> str:
    clocks = (f"SM clock {gpu.get('clocks_sm', '?')} of {gpu.get('clocks_max_sm', '?')} MHz, "
              f"memory clock {gpu.get('clocks_mem', '?')} MHz" if gpu else "no GPU")
    return (f"Device {device}: {gpu.get('gpu', 'no GPU')} ({clocks}; CUDA {env.get('cuda')}, "
            f"driver {gpu.get('driver_version', '?')}), {env.get('host_cpus')} host CPUs, "
            f"torch {env.get('torch')}, Python {env.get('python')}, ONNX Runtime "
            f"{env.get('onnxruntime')} ({', '.join(env.get('ort_providers', []))}). Every "
            f"speed at 480x640 unless the run was --quick.")


def _failure(rec: dict[str, Any] | None) -> str:
    """Why a step gave no figure, in one cell."""
    if rec is None:
        return "not run"
    if rec.get("skipped"):
        return f"skipped: {rec['skipped']}"
    tail = " ".join(rec.get("stderr_tail", [])[-1:]).replace("|", "/")
    return f"exit {rec.get('exit')}: {tail}"


def _result(records: dict[str, Any], name: str) -> dict[str, Any] | None:
    rec = records.get(name) or {}
    result = rec.get("result")
    return result if isinstance(result, dict) and rec.get("exit") in (0, 1) else None


def gate_workload_ms(gate: dict[str, Any], workload: str) -> float | None:
    """The gate's median pass (``workload_ms``) of ``workload`` anywhere in its ``--json``."""
    for item in _dicts(gate):
        if item.get("name") == workload and isinstance(item.get("workload_ms"), int | float):
            return float(item["workload_ms"])
    return None


def _dicts(node: Any) -> Iterator[dict[str, Any]]:
    if isinstance(node, dict):
        yield node
        for value in node.values():
            yield from _dicts(value)
    elif isinstance(node, list):
        for value in node:
            yield from _dicts(value)


def agreement_rows(records: dict[str, Any]) -> list[Row]:
    gate = _result(records, "a/gate")
    rows = []
    for name in records:
        if not name.startswith("a/speed/"):
            continue
        net = name.split("/")[-1]
        speed = _result(records, name)
        gate_ms = gate_workload_ms(gate, f"net/{net}/torch") if gate else None
        if speed is None or gate_ms is None:
            why = _failure(records.get(name)) if speed is None else _failure(records.get("a/gate"))
            rows.append(Row("a", f"{net}: speed vs gate, ms", f"not measured ({why})"))
            continue
        diff = speed["ms_median"] / gate_ms - 1
        verdict = "within" if abs(diff) <= AGREEMENT_GOAL else "outside"
        rows.append(Row("a", f"{net}: speed vs gate (1 host thread), ms",
                        f"{speed['ms_median']:.2f} vs {gate_ms:.2f} ({100 * diff:+.1f} %)",
                        f"{verdict} the 5 % goal; speed's bound: "
                        f"{(speed.get('busy') or {}).get('bound')}"))
    return rows


def sweep_rows(records: dict[str, Any]) -> list[Row]:
    rows = []
    for name in records:
        if not name.startswith("b/sweep/"):
            continue
        net = name.split("/")[-1]
        r = _result(records, name)
        if r is None:
            rows.append(Row("b", f"{net}: backend sweep", _failure(records.get(name))))
            continue
        for v in r["results"]:
            rows.append(Row("b", f"{net}: {v['variant']}", *_variant_cells(v, r["fastest"])))
    return rows


def _variant_cells(v: dict[str, Any], fastest: str | None) -> tuple[str, str]:
    if v["status"] != "timed":
        return f"{v['status']}: {v['why']}".replace("|", "/"), ""
    labels = ("labels equal" if v["label_agreement"] == 1.0
              else f"labels {100 * v['label_agreement']:.3f} %")
    labels += "" if v["qualifies"] else " (fails)"
    compile_s = f", compile {v['compile_s']:.0f} s" if v.get("compile_s") else ""
    mark = "**fastest with eager fp32's labels**; " if v["variant"] == fastest else ""
    return (f"{v['ms_median']:.2f} ms ({v['speedup']:.2f}x eager fp32)",
            f"{mark}{labels}, {v.get('bound') or '?'}-bound{compile_s}")


def ratio_rows(records: dict[str, Any]) -> list[Row]:
    """FEAGNet / ESANet speed ratios from the sweeps, eager and with CUDA graphs, beside the
    paper's."""
    ref = _result(records, f"b/sweep/{REFERENCE}")
    rows: list[Row] = []
    if ref is None:
        return rows
    for net in ("feagnet-v2", "feagnet-v1", "feagnet-s"):
        r = _result(records, f"b/sweep/{net}")
        if r is None:
            continue
        paper = PAPER_FPS.get(net)
        beside = f"paper {paper / PAPER_FPS[REFERENCE]:.2f}" if paper else ""
        for variant in ("eager-fp32", "cuda-graph-fp32", "eager-fp16", "cuda-graph-fp16"):
            a, b = _variant_ms(r, variant), _variant_ms(ref, variant)
            if a and b:
                rows.append(Row("b", f"{net} / {REFERENCE} speed, {variant}", f"{b / a:.2f}",
                                beside))
    return rows


def _variant_ms(sweep: dict[str, Any], variant: str) -> float | None:
    return next((v["ms_median"] for v in sweep["results"]
                 if v["variant"] == variant and v["status"] == "timed"), None)


def batch_rows(records: dict[str, Any]) -> list[Row]:
    rows = []
    for name in records:
        if not name.startswith("c/batch/"):
            continue
        r = _result(records, name)
        if r is None:
            rows.append(Row("c", f"{name.split('/')[-1]}: batch sweep",
                            _failure(records.get(name))))
            continue
        for p in r["points"]:
            if p["refused"]:
                rows.append(Row("c", f"{p['network']}, batch {p['batch']}", p["refused"]))
                continue
            ratio = (f"{p['ratio_to_reference']:.2f}x {REFERENCE}"
                     if p["ratio_to_reference"] and p["network"] != REFERENCE else "")
            rows.append(Row("c", f"{p['network']}, batch {p['batch']}",
                            f"{p['fps_per_image']:.1f} FPS/image ({p['ms_median']:.2f} ms a "
                            f"pass)", ratio))
    return rows


def map_rows(records: dict[str, Any]) -> list[Row]:
    rows = []
    for name in records:
        if not name.startswith("d/map/"):
            continue
        r = _result(records, name)
        if r is None:
            rows.append(Row("d", "EVSMap end to end", _failure(records.get(name))))
            continue
        loop = r.get("loop") or {}
        shares = ", ".join(f"{k} {v:.1f} ms ({100 * (loop.get('shares') or {}).get(k, 0):.0f} %)"
                           for k, v in (r.get("stage_ms_median") or {}).items())
        goal = "reaches" if r.get("wall_hz", 0) >= MAP_GOAL_HZ else "below"
        plan = r.get("thread_plan")
        rows.append(Row("d", f"EVSMap end to end, {r.get('frames')} frames",
                        f"wall {r.get('wall_hz', 0):.1f} Hz; stages (share of a frame): "
                        f"{shares}", f"{goal} the {MAP_GOAL_HZ:g} Hz goal; bound "
                        f"{loop.get('bound')}, {100 * loop.get('reached', 0):.0f} % of its rate"
                        + (f"; thread plan {json.dumps(plan)}".replace("|", "/")
                           if plan else "")))
    return rows


def resume_rows(records: dict[str, Any]) -> list[Row]:
    cmp_ = records.get("e/train/compare", {})
    if "error" in cmp_ or not cmp_:
        return [Row("e", "resume proof (--deterministic)", cmp_.get("error", "not run"))]
    r = cmp_["resumed"]
    return [Row("e", "resume proof: 2 epochs straight vs 1 + --resume + 1 (--deterministic)",
                f"weights equal {r['equal']} (largest difference {r['max_abs_diff']:.3g}), "
                f"momentum equal {r['momentum_equal']}, AMP scaler equal {r['scaler_equal']}")]


def gate_rows(records: dict[str, Any]) -> list[Row]:
    rec = records.get("f/gate-update") or {}
    gate = _result(records, "f/gate-update")
    if gate is None:
        return [Row("f", "gate --update (this GPU kind)", _failure(rec or None))]
    figures = []
    for item in _dicts(gate):
        if str(item.get("name", "")).startswith("net/") and "workload_ms" in item:
            figures.append(f"{item['name']} {item['workload_ms']:.2f} ms")
    return [Row("f", "gate --update (this GPU kind, gpu_baseline.json)",
                "; ".join(dict.fromkeys(figures)) or f"exit {rec.get('exit')}")]


if __name__ == "__main__":
    sys.exit(main())
