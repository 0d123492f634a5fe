"""Top-1 agreement of int8 with fp32, per int8 scheme, on this machine's instruction set.

The figures behind :data:`evsmap.segmenters.quantize.AUTO_SCHEMES` (docs/int8.md, "Per
instruction set"). For each network: seeded weights, BatchNorm statistics re-estimated on the
calibration frames (:func:`~evsmap.segmenters.quantize.reestimate_batchnorm`: activations of a
trained network's scale), each scheme calibrated on evenly spaced frames of the synthetic living
room, top-1 agreement with fp32 on held-out frames of the synthetic office, per frame (worst and
mean), and the SQNR of the logits (int8 against fp32, dB, over all held-out frames: a deep
untrained network's argmax flips on tiny margins, so its agreement is a floor that says little,
while the SQNR still ranks the schemes). Run it natively, and under
``benchmarks/emulate_isa.py --python-args --`` for another kind:

    python benchmarks/int8_schemes.py --out reports/int8-schemes/avx512-vnni.json
    python benchmarks/emulate_isa.py --python-args -- benchmarks/int8_schemes.py \\
        --out reports/int8-schemes/avx2.json

The test network of ``tests/segmenters`` is ``tiny`` (its frames: 96x64, as the test uses them).
Agreement only: times taken under an emulator mean nothing, and ``nox -s bench -- -k realtime``
times the schemes natively.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _frames(scene: str, seed: int, count: int, size: tuple[int, int], pick: int):
    from evsmap.segmenters.quantize import evenly_spaced
    from evsmap.synth.sequence import SyntheticSequence

    seq = SyntheticSequence(scene=scene, seed=seed, frames=count, width=size[1],
                            height=size[0])
    return [seq.frame(i) for i in evenly_spaced(len(seq), pick)]


def _make(name: str, size: tuple[int, int]):
    import torch

    if name == "tiny":
        from tests.segmenters.int8_net import tiny_segmenter

        return tiny_segmenter(backend="onnxruntime")
    from evsmap.registry import SEGMENTERS

    torch.manual_seed(0)
    return SEGMENTERS.create(name, backend="onnxruntime", input_size=size)


def measure(name: str, schemes: list[str], size: tuple[int, int], calibration: int,
            held_out: int, cache_dir: Path | None) -> dict:
    """Agreement per scheme of network ``name`` at ``size`` (H, W)."""
    import numpy as np

    from evsmap.segmenters.quantize import reestimate_batchnorm, resolve_scheme

    frame_size = (64, 96) if name == "tiny" else size
    cal = _frames("living_room", 0, 60, frame_size, calibration)
    held = _frames("office", 1, held_out, frame_size, held_out)
    fp32 = _make(name, size)
    reestimate_batchnorm(fp32.module, [fp32.preprocess(f) for f in cal])
    reference = [fp32.logits(fp32.preprocess(f)) for f in held]
    out: dict = {"input": list(fp32.input_size), "schemes": {}}
    for scheme in schemes:
        t0 = time.perf_counter()
        seg = _make(name, size)
        seg.module.load_state_dict(fp32.module.state_dict())
        seg.calibrate(cal, scheme=resolve_scheme(scheme)[0], cache_dir=cache_dir)
        logits = [seg.logits(seg.preprocess(f)) for f in held]
        per_frame = [float((q.argmax(1) == ref.argmax(1)).float().mean())
                     for q, ref in zip(logits, reference, strict=True)]
        noise = sum(float(((q - ref) ** 2).sum()) for q, ref in zip(logits, reference,
                                                                    strict=True))
        signal = sum(float((ref ** 2).sum()) for ref in reference)
        sqnr = 10 * np.log10(signal / noise) if noise > 0 else float("inf")
        out["schemes"][scheme] = {"worst": min(per_frame), "mean": float(np.mean(per_frame)),
                                  "per_frame": per_frame, "logits_sqnr_db": float(sqnr),
                                  "seconds": round(time.perf_counter() - t0, 1)}
        print(f"{name:18s} {scheme:5s} agreement worst {min(per_frame):.4f} mean "
              f"{np.mean(per_frame):.4f}  logits SQNR {sqnr:5.1f} dB", flush=True)
    return out


def markdown(records: list[dict]) -> str:
    """One table of several runs' records (e.g. two instruction sets): a row per network and
    scheme, per run the worst-frame and mean agreement and the logits SQNR."""
    head = "| network | scheme |" + "".join(
        f" {r['machine']['instruction_set']}: worst / mean agreement, SQNR (dB) |"
        for r in records)
    lines = [head, "|---|---|" + "---:|" * len(records)]
    for name in records[0]["networks"]:
        for scheme in records[0]["networks"][name]["schemes"]:
            cells = []
            for r in records:
                m = r["networks"].get(name, {}).get("schemes", {}).get(scheme)
                mark = " (auto)" if r["auto_scheme"] == scheme else ""
                cells.append("not measured" if m is None else
                             f"{m['worst']:.3f} / {m['mean']:.3f}, {m['logits_sqnr_db']:.1f}"
                             f"{mark}")
            lines.append(f"| {name} | {scheme} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    from evsmap.environment import describe
    from evsmap.segmenters.quantize import SCHEMES, auto_scheme

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--networks", default="tiny,feagnet-v1",
                   help="comma-separated: 'tiny' (the tests' network) or registered names "
                        "(default tiny,feagnet-v1)")
    p.add_argument("--schemes", default=",".join(SCHEMES),
                   help=f"comma-separated (default {','.join(SCHEMES)})")
    p.add_argument("--size", default="320x256", metavar="WxH",
                   help="input size of the registered networks (default 320x256; ESANet "
                        "needs multiples of 32)")
    p.add_argument("--calibration-frames", type=int, default=8)
    p.add_argument("--held-out", type=int, default=4)
    p.add_argument("--cache-dir", type=Path, metavar="DIR",
                   help="where the exports and int8 models go (default: evsmap's ONNX cache, "
                        "$EVSMAP_CACHE_DIR/onnx or ~/.cache/evsmap/onnx)")
    p.add_argument("--out", type=Path, help="write the record as JSON here")
    p.add_argument("--table", type=Path, nargs="+", metavar="JSON",
                   help="print the Markdown table of these records (written by --out) and "
                        "exit")
    ns = p.parse_args(argv)
    if ns.table:
        print(markdown([json.loads(path.read_text()) for path in ns.table]))
        return 0
    w, h = (int(v) for v in ns.size.lower().split("x"))
    machine = describe()
    record = {"machine": machine, "auto_scheme": auto_scheme(), "networks": {},
              "settings": {"calibration_frames": ns.calibration_frames,
                           "held_out": ns.held_out, "size": [h, w]}}
    print(f"{machine['cpu']}, {machine['instruction_set']}: auto = {auto_scheme()}",
          flush=True)
    for name in ns.networks.split(","):
        record["networks"][name] = measure(name, ns.schemes.split(","), (h, w),
                                           ns.calibration_frames, ns.held_out, ns.cache_dir)
        if ns.out:
            ns.out.parent.mkdir(parents=True, exist_ok=True)
            ns.out.write_text(json.dumps(record, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
