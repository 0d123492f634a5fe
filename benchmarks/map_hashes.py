"""The sha256 of every file each registered map updater writes, and of its leaves, on a fixed small
synthetic sequence: run it before and after a change to the map code, and compare the outputs
(they must be equal line for line).

    python benchmarks/map_hashes.py [--frames N] [--resolution R] [--out FILE]

For each updater in the registry (``evsmap list``) and each front end it offers, it maps the
synthetic sequence (noise on, seed fixed) with the oracle's observations, then prints one line per
written file: ``.bt`` and every ``.ot`` file format the updater offers (``file_formats()``), the
full file once more after :meth:`restore` (a restored map writes the same bytes) and after one
more frame on the restored map, and one line for the leaf arrays (codes, log-odds, each payload)
where the updater keeps them. Updaters whose library is missing (``octomap-cpp`` without
``octomap-python``) print ``skipped``.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import tempfile
from pathlib import Path

import numpy as np

from evsmap.registry import READERS, SEGMENTERS, UPDATERS

FRONT_ENDS = {"multiclass-bayes": ("generator", "direct"),
              "classic-semantic": ("generator", "direct"),
              "classic-semantic-max": ("generator", "direct")}
"""The updaters with a ``front_end`` option, and its values (the others have one front end)."""


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _leaf_digest(updater) -> str | None:
    """sha256 over the leaf arrays: codes, log-odds and every payload in name order."""
    leaves = getattr(updater, "map", None)
    if leaves is None or not hasattr(leaves, "codes"):
        return None
    h = hashlib.sha256()
    for array in [leaves.codes, leaves.logodds] + [leaves.payload(n)
                                                   for n in sorted(leaves.payload_names)]:
        a = np.ascontiguousarray(array)
        h.update(str((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def _inputs(frames: int):
    seq = READERS.create("synthetic", frames=frames, width=160, height=120, noise=True)
    picked = [seq.frame(i) for i in range(len(seq))]
    oracle = SEGMENTERS.create("oracle", profile="per-pixel", seed=0)
    return picked, [oracle.predict(f) for f in picked]


def _variants() -> list[tuple[str, dict[str, str]]]:
    out: list[tuple[str, dict[str, str]]] = []
    for name in UPDATERS.names():
        for front_end in FRONT_ENDS.get(name, (None,)):
            out.append((name, {} if front_end is None else {"front_end": front_end}))
    return out


def _hash_variant(name: str, options: dict, resolution: float, frames, observations,
                  folder: Path) -> list[str]:
    label = name + "".join(f" {k}={v}" for k, v in options.items())
    try:
        make = lambda: UPDATERS.create(name, resolution=resolution, **options)  # noqa: E731
        updater = make()
    except ImportError as exc:
        return [f"{label}\tskipped ({exc})"]
    for frame, obs in zip(frames, observations, strict=True):
        updater.integrate(frame, obs)
    lines = []
    for fmt in ("bt",) + tuple(updater.file_formats()):
        path = folder / (f"{name}.bt" if fmt == "bt" else f"{name}-{fmt}.ot")
        if fmt == "bt":
            updater.write(path)
        else:
            updater.write(path, file_format=fmt)
        lines.append(f"{label}\t{fmt}\t{_digest(path.read_bytes())}")
    leaves = _leaf_digest(updater)
    if leaves is not None:
        lines.append(f"{label}\tleaves\t{leaves}")
    if hasattr(updater, "restore"):
        full = folder / f"{name}-full.ot"
        again = make().restore(full)
        again.write(folder / "again.ot")
        lines.append(f"{label}\trestored full\t{_digest((folder / 'again.ot').read_bytes())}")
        again.integrate(frames[0], observations[0])
        updater.integrate(frames[0], observations[0])
        again.write(folder / "again.ot")
        updater.write(folder / "first.ot")
        lines.append(f"{label}\trestored + 1 frame\t"
                     f"{_digest((folder / 'again.ot').read_bytes())} "
                     f"(unrestored: {_digest((folder / 'first.ot').read_bytes())})")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--resolution", type=float, default=0.05)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    frames, observations = _inputs(args.frames)
    lines = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, options in _variants():
            lines += _hash_variant(name, options, args.resolution, frames, observations,
                                   Path(tmp))
    text = "\n".join(lines) + "\n"
    if args.out is not None:
        args.out.write_text(text)
    sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
