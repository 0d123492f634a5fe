"""Do ``evsmap speed`` and the gate time a network's pass alike? (issue 53: one timing
definition, :mod:`evsmap.measure.pass_timing`.)

For each network, ``--rounds`` rounds alternate the two in fresh processes, at the same host
threads, pinned CPU and input size (480x640, the gate's): ``evsmap speed NET --threads T
--height 480 --width 640 --json`` and ``evsmap gate --only net/NET/torch --threads T --stored
--results FILE``. A shared machine drifts between two processes by more than either's own
interval, so the comparison is the median over rounds of each round's ratio (the two taken
minutes apart at most), with the rounds' spread::

    python benchmarks/timer_agreement.py [--networks feagnet-v2,esanet-r34-nbt1d]
        [--rounds 3] [--threads 1] [--device cpu] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any


def evsmap(*args: str) -> list[str]:
    return [sys.executable, "-m", "evsmap", *args]


def speed_ms(net: str, args: argparse.Namespace) -> dict[str, Any]:
    out = subprocess.run(evsmap("speed", net, "--threads", str(args.threads), "--device",
                                args.device, "--height", "480", "--width", "640", "--runs",
                                str(args.runs), "--json"),
                         capture_output=True, text=True, check=True).stdout
    r = json.loads(out)
    return {"ms": r["ms_median"], "ci_ms": r["ci_ms"], "cpus": r["timing"]["cpus"]}


def gate_ms(net: str, args: argparse.Namespace, work: Path) -> dict[str, Any]:
    results = work / f"{net}.json"
    subprocess.run(evsmap("gate", "--only", f"net/{net}/torch", "--threads", str(args.threads),
                          "--device", args.device, "--stored", "--budget", str(args.budget),
                          "--confirm", "0", "--results", str(results), "--overwrite"),
                   capture_output=True, text=True, check=False)
    w = json.loads(results.read_text())["workloads"][f"net/{net}/torch"]
    return {"ms": w["workload_ms"], "ci_ms": w["workload_ci_ms"], "cpus": w["timing"]["cpus"]}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--networks", default="feagnet-v2,esanet-r34-nbt1d")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--runs", type=int, default=15, help="speed's timed passes")
    p.add_argument("--budget", type=float, default=15.0, help="the gate's seconds of pairs")
    p.add_argument("--device", default="cpu")
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    from evsmap.environment import describe

    machine = describe()
    print(f"# {machine['cpu']} ({machine['instruction_set']}), {args.threads} host thread(s), "
          f"{args.device}, 480x640, {args.rounds} rounds")
    summary = {"machine": machine, "settings": vars(args) | {"json": None}, "networks": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for net in args.networks.split(","):
            rounds = []
            for i in range(args.rounds):
                s, g = speed_ms(net, args), gate_ms(net, args, Path(tmp))
                rounds.append({"speed": s, "gate": g, "ratio": s["ms"] / g["ms"]})
                print(f"{net} round {i + 1}: speed {s['ms']:.1f} ms "
                      f"[{s['ci_ms'][0]:.1f}, {s['ci_ms'][1]:.1f}], gate {g['ms']:.1f} ms "
                      f"[{g['ci_ms'][0]:.1f}, {g['ci_ms'][1]:.1f}], ratio {s['ms'] / g['ms']:.3f}",
                      flush=True)
            ratios = [r["ratio"] for r in rounds]
            summary["networks"][net] = {"rounds": rounds, "median_ratio": statistics.median(ratios),
                                        "min_ratio": min(ratios), "max_ratio": max(ratios)}
            print(f"{net}: speed / gate median {statistics.median(ratios):.3f} "
                  f"(rounds {min(ratios):.3f} to {max(ratios):.3f})", flush=True)
    if args.json:
        args.json.write_text(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
