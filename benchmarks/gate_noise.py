"""The gate's own noise: run ``evsmap gate`` N times on an unchanged tree, against one baseline
or (``--against REF``) paired with a reference commit measured beside it, and report the
false-alarm rate (runs that failed) and, per workload, the spread of the time ratio and peak
changes the gate judged. This is how docs/gates.md's figures were taken.

    python benchmarks/gate_noise.py --runs 10 --out /tmp/gate-noise [--baseline FILE]
        [--against REF] [--only PATTERN ...] [--budget S] [--confirm N]

Every run's ``--results`` JSON and printed table are kept under ``--out``; ``summary.md`` holds
the table below. Run it on an otherwise idle machine (the load average is recorded per run).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def _run(i: int, args: argparse.Namespace) -> dict:
    results = args.out / f"run{i:02d}.json"
    cmd = [sys.executable, "-m", "evsmap", "gate", "--baseline", str(args.baseline),
           "--results", str(results), "--overwrite", "--budget", str(args.budget),
           "--confirm", str(args.confirm)]
    if args.only:
        cmd += ["--only", *args.only]
    if args.against:
        cmd += ["--against", args.against]
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    (args.out / f"run{i:02d}.txt").write_text(proc.stdout + proc.stderr)
    data = json.loads(results.read_text())
    return {"run": i, "exit": proc.returncode, "seconds": seconds, "load_before": load,
            "workloads": data["workloads"], "rows": data.get("rows", []),
            "pairs": data.get("pairs", {})}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--runs", type=int, default=10)
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--baseline", type=Path, default=Path("benchmarks/baseline.json"))
    p.add_argument("--only", nargs="+")
    p.add_argument("--budget", type=float, default=4.0)
    p.add_argument("--confirm", type=int, default=4)
    p.add_argument("--against", metavar="REF", help="paired runs against this commit")
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    runs = []
    for i in range(args.runs):
        runs.append(_run(i, args))
        r = runs[-1]
        print(f"run {i}: exit {r['exit']}, {r['seconds']:.0f} s, load before "
              f"{r['load_before']:.2f}", flush=True)
    mode = f"paired against {args.against}" if args.against else f"against {args.baseline}"
    lines = [f"# Gate noise: {args.runs} runs of an unchanged tree, {mode}", "",
             "| run | exit | seconds | load before | outside the band after the first pass "
             "(measured again) | failed workloads |", "|---|---|---|---|---|---|"]
    changes: dict[str, dict[str, list[float]]] = {}
    for r in runs:
        failed = sorted({row["workload"] for row in r["rows"] if row["verdict"] == "FAIL"})
        again = sorted(k for k, rec in r["workloads"].items()
                       if len(r["pairs"].get(k, [])) > 1 or len(rec.get("processes", [])) > 1)
        lines.append(f"| {r['run']} | {r['exit']} | {r['seconds']:.0f} | "
                     f"{r['load_before']:.2f} | {', '.join(again) or '-'} | "
                     f"{', '.join(failed) or '-'} |")
        for row in r["rows"]:
            if row["measure"] in ("time_ratio", "peak_rss_bytes") and row["change"] is not None:
                c = changes.setdefault(row["workload"], {"time_ratio": [], "peak_rss_bytes": []})
                c[row["measure"]].append(row["change"])
    alarms = sum(1 for r in runs if r["exit"] != 0)
    lines += ["", f"False alarms: {alarms} of {len(runs)} runs.", "",
              "| workload | time change median | min | max | peak change median | min | max |",
              "|---|---|---|---|---|---|---|"]
    for name in sorted(changes):
        t = np.asarray(changes[name]["time_ratio"])
        m = np.asarray(changes[name]["peak_rss_bytes"])
        lines.append(f"| {name} | {np.median(t):+.1%} | {t.min():+.1%} | {t.max():+.1%} | "
                     f"{np.median(m):+.1%} | {m.min():+.1%} | {m.max():+.1%} |")
    every_t = np.concatenate([np.asarray(c["time_ratio"]) for c in changes.values()])
    every_m = np.concatenate([np.asarray(c["peak_rss_bytes"]) for c in changes.values()])
    lines += ["", f"All workloads and runs: time change |median| "
              f"{np.median(np.abs(every_t)):.1%}, 95th percentile of |change| "
              f"{np.percentile(np.abs(every_t), 95):.1%}, largest {every_t.max():+.1%} / "
              f"{every_t.min():+.1%}; peak change 95th percentile "
              f"{np.percentile(np.abs(every_m), 95):.1%}, largest {every_m.max():+.1%} / "
              f"{every_m.min():+.1%}."]
    (args.out / "summary.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
