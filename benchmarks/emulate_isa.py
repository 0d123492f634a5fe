"""Run evsmap's machine-dependent tests (or any Python command) on an emulated instruction set.

CI and sessions land on machines of different kinds (AMD EPYC with AVX-512 VNNI, or with AVX2
and FMA only); a test whose expectation depends on the kind must hold on both. This runs the
command under QEMU's user-mode emulator (``qemu-x86_64``, Debian's package ``qemu-user``) with
a CPU model that lacks the wider sets, so that CPUID - which NumPy, torch and ONNX Runtime
pick their kernels by - reports only what the emulated CPU has:

    python benchmarks/emulate_isa.py                        # pytest -m isa on AVX2
    python benchmarks/emulate_isa.py --isa avx -- -k quantize
    python benchmarks/emulate_isa.py --python-args -- benchmarks/int8_schemes.py --out x.json
    python benchmarks/emulate_isa.py --python-args -- -m evsmap speed feagnet-v1 \
        --precision int8 --json

Before running, it checks under the emulator that :func:`evsmap.environment.instruction_set`
names the set asked for, and refuses otherwise. Emulation is exact for integer arithmetic (the
saturation of ``VPMADDUBSW`` included) and slow (10-40x): times measured under it mean nothing.
Not a test: CI has no emulator (docs/int8.md, "Per instruction set").
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CPU_MODELS = {"avx2": "max", "avx": "SandyBridge", "sse4.2": "Nehalem"}
"""QEMU CPU model per instruction set. QEMU's TCG implements AVX2 and FMA but no AVX-512 (QEMU
7.2-9.x), so ``max`` is an AVX2 machine without VNNI."""


def emulated_isa(qemu: str, model: str) -> str:
    """The instruction set evsmap reads inside the emulator."""
    probe = "from evsmap.environment import instruction_set; print(instruction_set())"
    out = subprocess.run([qemu, "-cpu", model, sys.executable, "-c", probe], cwd=ROOT,
                         capture_output=True, text=True, check=False)
    return out.stdout.strip().splitlines()[-1] if out.stdout.strip() else out.stderr.strip()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--isa", choices=sorted(CPU_MODELS), default="avx2",
                   help="instruction set to emulate (default avx2)")
    p.add_argument("--python-args", action="store_true",
                   help="the arguments are a Python command line (default: pytest's, after "
                        "'-m isa tests')")
    argv = sys.argv[1:] if argv is None else list(argv)
    rest: list[str] = []
    if "--" in argv:
        at = argv.index("--")
        argv, rest = argv[:at], argv[at + 1:]
    p.epilog = ("Arguments after -- go to pytest (after '-m isa tests -q') or, with "
                "--python-args, to the interpreter.")
    ns = p.parse_args(argv)
    qemu = shutil.which("qemu-x86_64")
    if qemu is None:
        print("emulate_isa: qemu-x86_64 not found (Debian: apt-get install qemu-user)",
              file=sys.stderr)
        return 2
    model = CPU_MODELS[ns.isa]
    seen = emulated_isa(qemu, model)
    if seen != ns.isa:
        print(f"emulate_isa: qemu -cpu {model} gives instruction set {seen!r}, not "
              f"{ns.isa!r}", file=sys.stderr)
        return 2
    if ns.python_args:
        if not rest:
            print("emulate_isa: --python-args needs a command after --", file=sys.stderr)
            return 2
        command = rest
    else:
        command = ["-m", "pytest", "-p", "no:cacheprovider", "-m", "isa", "tests", "-q", *rest]
    print(f"emulate_isa: {ns.isa} (qemu -cpu {model}): python {' '.join(command)}",
          file=sys.stderr, flush=True)
    env = {**os.environ, "EVSMAP_EMULATED_ISA": ns.isa}
    return subprocess.run([qemu, "-cpu", model, sys.executable, *command], cwd=ROOT,
                          env=env, check=False).returncode


if __name__ == "__main__":
    sys.exit(main())
