"""Write ``tests/mapping/data/std_sort_orders.npz``: inputs and the orders libstdc++'s
``std::sort`` (and its introsort loop at low depth limits, to reach the heapsort) leaves them in,
from ``benchmarks/std_sort_reference.cpp`` compiled with the machine's g++.

Usage: python benchmarks/std_sort_fixture.py [--out PATH]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE.parent / "tests" / "mapping" / "data" / "std_sort_orders.npz"


def cases(seed: int = 5) -> list[tuple[np.ndarray, int]]:
    """Inputs like PCL's leaf indices (few distinct values, runs of equal keys), sorted and
    reversed runs, and short ones around the insertion-sort threshold; some at a depth limit
    low enough for the heapsort."""
    rng = np.random.default_rng(seed)
    out = []
    for n in (2, 3, 15, 16, 17, 18, 33, 100, 257, 1000, 4000):
        for distinct in (1, 3, max(2, n // 8), n):
            out.append((rng.integers(0, distinct, n), -1))
    out.append((np.repeat(np.arange(50), 40), -1))
    out.append((np.repeat(np.arange(50), 40)[::-1].copy(), -1))
    ramp = np.arange(600) % 37
    out.append((np.concatenate([ramp, ramp[::-1]]), -1))
    for depth in (0, 1, 2, 3):
        for n in (17, 40, 300, 2000):
            out.append((rng.integers(0, max(2, n // 5), n), depth))
    return out


def reference_orders(binary: Path, items: list[tuple[np.ndarray, int]]) -> list[np.ndarray]:
    text = "".join(f"{len(k)} {d} {' '.join(map(str, k.tolist()))}\n" for k, d in items)
    done = subprocess.run([str(binary)], input=text, capture_output=True, text=True, check=True)
    return [np.array(line.split(), dtype=np.int64) for line in done.stdout.splitlines()]


def build(workdir: Path) -> Path:
    binary = workdir / "std_sort_reference"
    subprocess.run(["g++", "-O2", "-std=c++11", "-o", str(binary),
                    str(HERE / "std_sort_reference.cpp")], check=True)
    return binary


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = ap.parse_args(argv)
    items = cases()
    with tempfile.TemporaryDirectory() as tmp:
        orders = reference_orders(build(Path(tmp)), items)
    keys = [k for k, _ in items]
    np.savez_compressed(args.out, keys=np.concatenate(keys),
                        orders=np.concatenate(orders),
                        lengths=np.array([len(k) for k in keys]),
                        depths=np.array([d for _, d in items]))
    print(f"wrote {len(items)} cases to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
