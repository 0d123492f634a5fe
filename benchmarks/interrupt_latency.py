"""How long evsmap takes to stop on Ctrl-C or SIGTERM (issue 21: within 2 s, nothing left).

    python benchmarks/interrupt_latency.py [--trials N] [--seed S] [--json FILE]

For each command (a ``reproduce --quick`` subset with a process pool and a timed cell, an
``evsmap map`` of the synthetic room) and each signal (SIGINT to the process group, as a
terminal's Ctrl-C; SIGTERM to the process), ``--trials`` runs are signalled at random moments
(uniform over the first seconds of the run, seeded). The latency is the time from the signal to
the process's exit (``waitpid``), and the leftovers are the processes of the run (marked through
their environment) still alive 0.5 s after it. Printed: median, IQR and maximum per command and
signal, with the machine's load average before and after, since a busy machine stretches them.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

COMMANDS = {
    "reproduce": (["reproduce", "--quick", "--tables", "I", "--cells",
                   "table1/feagnet-v1/complexity*,table1/feagnet-v2/complexity*,"
                   "table1/feagnet-v1/speed*", "--out", "{out}"], 2.0, 25.0),
    "map": (["map", "synthetic", "--updater", "multiclass-bayes", "-r", "width=320", "-r",
             "height=240", "-r", "frames=60", "--out", "{out}/map.ot"], 1.5, 10.0),
}
"""name -> (arguments, earliest and latest moment of the signal in seconds)."""


def _marked(mark: str) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if mark.encode() in (entry / "environ").read_bytes():
                    found.append(int(entry.name))
            except OSError:
                continue
    return found


def one_trial(argv: list[str], after_s: float, sig: int, group: bool) -> dict:
    mark = uuid.uuid4().hex
    with tempfile.TemporaryDirectory(prefix="evsmap-interrupt-") as tmp:
        args = [a.replace("{out}", str(Path(tmp) / "out")) for a in argv]
        if args[0] == "map":
            Path(tmp, "out").mkdir()
        env = {**os.environ, "EVSMAP_BENCH_MARK": mark, "EVSMAP_DATA_ROOT": tmp}
        err_file = Path(tmp) / "stderr.txt"
        with open(err_file, "w") as err_fh:
            proc = subprocess.Popen([sys.executable, "-m", "evsmap", *args], env=env,
                                    stdout=subprocess.DEVNULL, stderr=err_fh,
                                    start_new_session=True)
            time.sleep(after_s)
            if proc.poll() is not None:
                return {"after_s": after_s, "finished_first": True}
            sent = time.perf_counter()
            if group:
                os.killpg(proc.pid, sig)
            else:
                proc.send_signal(sig)
            proc.wait()
            latency = time.perf_counter() - sent
        err = err_file.read_text(errors="replace")
        time.sleep(0.5)
        left = _marked(mark)
        for pid in left:
            os.kill(pid, signal.SIGKILL)
        shutil.rmtree(Path(tmp) / "out", ignore_errors=True)
    return {"after_s": round(after_s, 3), "latency_s": round(latency, 4),
            "exit": proc.returncode, "left": len(left), "traceback": "Traceback" in err}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    rng = random.Random(args.seed)
    load_before = os.getloadavg()
    results: dict[str, dict] = {}
    for name, (cmd, lo, hi) in COMMANDS.items():
        for sig, group, label in ((signal.SIGINT, True, "ctrl-c"),
                                  (signal.SIGTERM, False, "sigterm")):
            trials = [one_trial(cmd, rng.uniform(lo, hi), sig, group)
                      for _ in range(args.trials)]
            lat = sorted(t["latency_s"] for t in trials if "latency_s" in t)
            q = statistics.quantiles(lat, n=4) if len(lat) >= 2 else [float("nan")] * 3
            results[f"{name}/{label}"] = {
                "trials": trials, "median_s": statistics.median(lat) if lat else None,
                "iqr_s": q[2] - q[0], "max_s": max(lat) if lat else None,
                "left": sum(t.get("left", 0) for t in trials),
                "tracebacks": sum(t.get("traceback", False) for t in trials)}
            r = results[f"{name}/{label}"]
            print(f"{name:<10} {label:<8} n={len(lat)}  median {r['median_s']:.3f} s  "
                  f"IQR {r['iqr_s']:.3f}  max {r['max_s']:.3f}  processes left {r['left']}  "
                  f"tracebacks {r['tracebacks']}", flush=True)
    load_after = os.getloadavg()
    print(f"load average before {load_before[0]:.2f}, after {load_after[0]:.2f} "
          f"({os.cpu_count()} cores)")
    if args.json:
        args.json.write_text(json.dumps({"results": results, "load_before": load_before,
                                         "load_after": load_after, "seed": args.seed},
                                        indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
