"""Prepare a gate run: find the workloads of this installation and make what they share.

``python -m evsmap.gate.prepare --workdir D`` does it in a process of its own and writes
``D/context.json`` (the samples' paths, the networks and updaters registered, the ONNX exports,
the observations the updaters integrate) and ``D/plan.json`` (the workloads): this is how
``evsmap gate --against REF`` prepares the reference commit's side with the reference's own
code. The candidate's side calls :func:`prepare` in the gate's process.

:data:`PROTOCOL` numbers what the two files and ``python -m evsmap.gate.worker`` exchange; the
two sides of a paired run must speak the same one.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from evsmap.errors import EvsmapError
from evsmap.gate.workloads import (
    MAP_NETWORK,
    NETWORK_SIZE,
    UPDATE_FRAMES,
    Workload,
    plan,
    select,
    selected_names,
    tum_sequence,
)

PROTOCOL = 1
CONTEXT_FILE = "context.json"
PLAN_FILE = "plan.json"


def _sample(folder: str) -> tuple[str | None, str | None]:
    from evsmap.paths import default_data_root

    path = default_data_root() / folder
    if path.exists():
        return str(path), None
    return None, (f"needs the sample {path} (data root: $EVSMAP_DATA_ROOT, ../shared/data or "
                  f"~/.cache/evsmap/data; `evsmap datasets fetch`)")


def discover(*, threads: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """The gate context (the samples' paths, the networks and the updaters registered here)
    and the seeded networks built to find out which segmenters are networks."""
    import torch

    from evsmap.registry import SEGMENTERS, UPDATERS

    context: dict[str, Any] = {"threads": threads, "networks": {},
                               "updaters": list(UPDATERS.names()), "missing": {},
                               "observations": None}
    context["tum"], context["missing"]["tum"] = _sample("tum_fr1_xyz")
    context["bag"], context["missing"]["bag"] = _sample("ros/lidar_odometry.bag")
    context["missing"]["observations"] = context["missing"]["tum"]
    torch.set_num_threads(threads)
    built = {}
    for name in SEGMENTERS.names():
        if SEGMENTERS.get(name).extras.get("gate") is False:
            # a plug-in that asks not to be gated (the compared networks of Tables I-II:
            # timed beside FEAGNet in every reproduce run; several are 100-500 GFLOPs)
            context.setdefault("not_gated", []).append(name)
            continue
        torch.manual_seed(0)
        try:
            segmenter = SEGMENTERS.create(name)
        except EvsmapError as exc:  # a plug-in that cannot be built with its defaults
            context["missing"][f"net:{name}"] = str(exc)
            continue
        if segmenter.module is None:
            continue  # not a network (the oracle)
        context["networks"][name] = {"uses_depth": bool(segmenter.uses_depth)}
        built[name] = segmenter
    return context, built


def prepare_inputs(context: dict[str, Any], built: dict[str, Any],
                   workloads: Sequence[Workload], out: Path, *,
                   log: Callable[[str], Any] = lambda _: None) -> None:
    """What the selected workloads share, into ``context``: the ONNX exports (in the export
    cache shared across runs) and the top-3 of the seeded FEAGNet-V1 on the TUM frames the
    updaters integrate (``out/observations.npz``)."""
    import torch

    from evsmap.models.onnx_export import cached_onnx
    from evsmap.registry import SEGMENTERS

    for w in workloads:
        if w.kind == "net" and w.name.endswith("/onnxruntime"):
            name = w.name.split("/")[1]
            segmenter, info = built[name], context["networks"][name]
            log(f"ONNX export of {name} (cached across runs)")
            try:
                info["onnx"] = str(cached_onnx(segmenter.module,
                                               segmenter.example_inputs(*NETWORK_SIZE),
                                               segmenter.input_names, key=name))
            except EvsmapError as exc:
                info["onnx_error"] = str(exc)
    if context["tum"] and any(w.kind == "update" for w in workloads):
        log(f"top-3 of the seeded {MAP_NETWORK} on {len(UPDATE_FRAMES)} TUM frames")
        torch.manual_seed(0)
        segmenter = SEGMENTERS.create(MAP_NETWORK)
        seq = tum_sequence(context["tum"])
        obs = [segmenter.predict(seq[i]) for i in UPDATE_FRAMES]
        path = out / "observations.npz"
        np.savez(path, classes=np.stack([o.classes for o in obs]),
                 probs=np.stack([o.probs for o in obs]), num_classes=obs[0].num_classes)
        context["observations"] = str(path)


def missing_input(workload: Workload, context: dict[str, Any]) -> str | None:
    """Why ``workload`` cannot run here, or None."""
    for need in workload.needs:
        if need in ("tum", "bag") and not context.get(need):
            return context["missing"].get(need) or f"needs {need}"
        if need == "observations" and not context.get("observations"):
            return context["missing"].get("observations") or "no observations were prepared"
    return None


def prepare(workdir: Path, *, threads: int, cpu: int, patterns: Sequence[str] | None = None,
            strict: bool = True, log: Callable[[str], Any] = lambda _: None,
            device: str = "cpu") -> tuple[dict[str, Any], list[Workload]]:
    """The gate context and the selected workloads, their shared inputs made in ``workdir``
    and both written there (:data:`CONTEXT_FILE`, :data:`PLAN_FILE`).

    ``patterns`` select workloads as ``--only`` does; ``strict=False`` lets a pattern match
    nothing (the reference commit of a paired run may not have a workload this tree has).

    Raises:
        EvsmapError: with ``strict``, a pattern matches no workload.
    """
    workdir.mkdir(parents=True, exist_ok=True)
    context, built = discover(threads=threads)
    context["device"] = device
    workloads = plan(context)
    if strict:
        chosen = select(workloads, patterns)
    else:
        names = selected_names([w.name for w in workloads], patterns)
        chosen = [w for w in workloads if w.name in names]
    context["cpus"] = [cpu]
    context["protocol"] = PROTOCOL
    prepare_inputs(context, built, chosen, workdir, log=log)
    del built
    (workdir / CONTEXT_FILE).write_text(json.dumps(context))
    (workdir / PLAN_FILE).write_text(json.dumps([dataclasses.asdict(w) for w in chosen]))
    return context, chosen


def read_prepared(workdir: Path) -> tuple[dict[str, Any], list[Workload]]:
    """What :func:`prepare` wrote in ``workdir``."""
    context = json.loads((workdir / CONTEXT_FILE).read_text())
    workloads = [Workload(**{**w, "needs": tuple(w.get("needs", ()))})
                 for w in json.loads((workdir / PLAN_FILE).read_text())]
    return context, workloads


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m evsmap.gate.prepare")
    p.add_argument("--workdir", required=True, type=Path)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--cpu", type=int, default=0)
    p.add_argument("--only", nargs="+", action="extend")
    args = p.parse_args(argv)
    try:
        prepare(args.workdir, threads=args.threads, cpu=args.cpu, patterns=args.only,
                strict=False, log=lambda msg: print(msg, file=sys.stderr, flush=True))
    except EvsmapError as exc:
        print(f"evsmap.gate.prepare: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
