"""What do ONNX Runtime's memory settings cost a speed cell, in peak memory and in pass time?
(issue 54, "Peak memory".)

A speed cell (``evsmap/runner/network_cells.py`` ``run_speed``) builds the network, takes its
cached size-free export, builds an ONNX Runtime session pinned to the cell's size
(``evsmap.models.speed_export.session_for``) and times passes. This script does the same for one
network and size under each of the session settings below, and prints one JSON record:

* ``--mode fresh`` (the peak): each setting in its own fresh process, in ``--rounds`` rounds
  whose order rotates; each process reports its peak RSS from its start (``process_peak``:
  what the cell's ``cell_peak_rss_bytes`` counts, the network and the export's leftovers
  included), the peak of the session's build and passes alone (``session_peak``, the kernel's
  counter reset after the export), and its passes' median.
* ``--mode interleave`` (the time): every setting's session in one process, their passes
  alternated one by one, so a load that comes and goes reaches them alike; the ratio of each
  median to the defaults' is the figure (the peaks are meaningless there).

Both report a digest of the logits of each setting's pass, so a setting that changed what the
pass computes shows::

    python benchmarks/ort_memory.py --table table2 --row ssma --size 1024x2048 \
        [--settings default,no-arena,no-pattern,neither] [--mode fresh] [--rounds 2] \
        [--warmup 2] [--passes 3] [--threads N] [--json FILE]

The export is made (and cached) by a first process before any measured one, so no measured
process pays for it.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

_ON = {"enable_cpu_mem_arena": True, "enable_mem_pattern": True}
SETTINGS: dict[str, dict[str, Any]] = {
    "default": _ON,
    "no-arena": {**_ON, "enable_cpu_mem_arena": False},
    "no-pattern": {**_ON, "enable_mem_pattern": False},
    "neither": {"enable_cpu_mem_arena": False, "enable_mem_pattern": False},
    "exact-arena": {**_ON, "arena_extend_strategy": "kSameAsRequested"},
    "exact-arena-no-pattern": {**_ON, "enable_mem_pattern": False,
                               "arena_extend_strategy": "kSameAsRequested"},
    "evsmap": {},  # what session_for gives a CPU session (SPEED_SESSION_MEMORY)
}
"""The candidate settings: ONNX Runtime's defaults, its CPU arena off, its memory pattern
(one block planned for all intermediates) off, both; the arena kept but grown by exactly what
is asked rather than to the next power of two (a process-wide arena registered with the
environment, ``session.use_env_allocators``); and ``evsmap``, what ``session_for`` gives a
speed cell's CPU session (``SPEED_SESSION_MEMORY``)."""


def _cell(table: str, row: str, size: tuple[int, int]):
    """The speed cell of ``table``'s ``row`` at ``size`` (Tables I-II's plan)."""
    from evsmap.tables.plan import expand_all

    for spec in expand_all():
        if (spec.kind == "speed" and spec.key.startswith(f"{table}/{row}/speed@")
                and tuple(spec.input_size or ()) == size and "#" not in spec.key):
            return spec
    raise SystemExit(f"no CPU speed cell {table}/{row} at {size[1]}x{size[0]}")


def _prepared(table: str, row: str, size: tuple[int, int]):
    """The cell's segmenter, inputs and cached export, as ``run_speed`` makes them."""
    from evsmap.models.speed_export import speed_export
    from evsmap.runner.network_cells import build_segmenter, cell_network

    spec = _cell(table, row, size)
    network = cell_network(spec)
    segmenter = build_segmenter(network, input_size=size)
    inputs = segmenter.example_inputs(*size)
    export = speed_export(segmenter.module, inputs, segmenter.input_names, key=network.spec)
    return segmenter, inputs, export


def _session(export, size: tuple[int, int], threads: int, setting: str):
    import onnxruntime as ort

    from evsmap.models.speed_export import session_for

    options = dict(SETTINGS[setting])
    strategy = options.pop("arena_extend_strategy", None)
    memory = options or None  # None: session_for's own settings
    if strategy is not None:
        _register_exact_arena(ort)
    config = {"session.use_env_allocators": "1"} if strategy is not None else None
    return session_for(export.path, threads=threads, free_dimensions=export.free_dimensions(*size),
                       memory=memory, config=config)


_REGISTERED = False


def _register_exact_arena(ort: Any) -> None:
    global _REGISTERED
    if _REGISTERED:
        return
    info = ort.OrtMemoryInfo("Cpu", ort.OrtAllocatorType.ORT_ARENA_ALLOCATOR, 0,
                             ort.OrtMemType.DEFAULT)
    ort.create_and_register_allocator(info, ort.OrtArenaCfg({"arena_extend_strategy": 1}))
    _REGISTERED = True


def _feeds(session, segmenter, inputs) -> dict[str, Any]:
    arrays = dict(zip(segmenter.input_names, (t.numpy() for t in inputs), strict=True))
    return {i.name: arrays[i.name] for i in session.get_inputs()}


def _digest(outputs: list[Any]) -> str:
    return hashlib.sha256(outputs[0].tobytes()).hexdigest()[:16]


def one_process(args: argparse.Namespace) -> dict[str, Any]:
    """One setting in this (fresh) process: peaks and pass times."""
    import gc

    from evsmap.measure.memory import current_rss, peak_rss, reset_peak, trim_heap

    size = _size(args.size)
    segmenter, inputs, export = _prepared(args.table, args.row, size)
    gc.collect()
    trim_heap()
    before = current_rss()
    reset_peak()
    t0 = time.perf_counter()
    session = _session(export, size, args.threads, args.setting)
    session_s = time.perf_counter() - t0
    after_build = current_rss()
    feeds = _feeds(session, segmenter, inputs)
    outputs = session.run(None, feeds)
    for _ in range(args.warmup - 1):
        session.run(None, feeds)
    times = []
    for _ in range(args.passes):
        t = time.perf_counter()
        session.run(None, feeds)
        times.append(1e3 * (time.perf_counter() - t))
    from evsmap.measure.memory import peak_since_mark

    return {"setting": args.setting, "rss_before_session": before,
            "rss_after_build": after_build, "session_peak": peak_rss(),
            "process_peak": peak_since_mark(), "session_s": session_s, "ms": times,
            "ms_median": statistics.median(times), "logits": _digest(outputs)}


def interleave(args: argparse.Namespace, settings: list[str]) -> dict[str, Any]:
    """Every setting's session in this process, passes alternated one by one."""
    size = _size(args.size)
    segmenter, inputs, export = _prepared(args.table, args.row, size)
    sessions = {s: _session(export, size, args.threads, s) for s in settings}
    feeds = {s: _feeds(sessions[s], segmenter, inputs) for s in settings}
    digests = {s: _digest(sessions[s].run(None, feeds[s])) for s in settings}
    for _ in range(args.warmup - 1):
        for s in settings:
            sessions[s].run(None, feeds[s])
    times: dict[str, list[float]] = {s: [] for s in settings}
    for i in range(args.passes):
        order = settings[i % len(settings):] + settings[:i % len(settings)]
        for s in order:
            t = time.perf_counter()
            sessions[s].run(None, feeds[s])
            times[s].append(1e3 * (time.perf_counter() - t))
    base = statistics.median(times[settings[0]])
    return {s: {"ms": times[s], "ms_median": statistics.median(times[s]),
                "ratio_to_first": statistics.median(times[s]) / base, "logits": digests[s]}
            for s in settings}


def fresh(args: argparse.Namespace, settings: list[str]) -> dict[str, Any]:
    """Each setting in its own process, ``--rounds`` rounds in rotating order."""
    _child(args, "default", warmup=1, passes=1)  # makes the export, so no measured run does
    rounds = []
    for r in range(args.rounds):
        order = settings[r % len(settings):] + settings[:r % len(settings)]
        rounds.append({s: _child(args, s, warmup=args.warmup, passes=args.passes)
                       for s in order})
    out: dict[str, Any] = {"rounds": rounds}
    for s in settings:
        ratios = [rd[s]["ms_median"] / rd[settings[0]]["ms_median"] for rd in rounds]
        out[s] = {"process_peak_gb": max(rd[s]["process_peak"] for rd in rounds) / 1e9,
                  "session_peak_gb": max(rd[s]["session_peak"] for rd in rounds) / 1e9,
                  "ms_medians": [rd[s]["ms_median"] for rd in rounds],
                  "ratio_to_first": ratios, "logits": sorted({rd[s]["logits"] for rd in rounds})}
    return out


def _child(args: argparse.Namespace, setting: str, *, warmup: int, passes: int) -> dict:
    cmd = [sys.executable, __file__, "--table", args.table, "--row", args.row, "--size", args.size,
           "--threads", str(args.threads), "--warmup", str(warmup), "--passes", str(passes),
           "--one", setting]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode:
        raise SystemExit(f"{setting}: {done.stderr.strip().splitlines()[-1:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _size(text: str) -> tuple[int, int]:
    h, w = (int(v) for v in text.lower().split("x"))
    return h, w


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--table", default="table2", help="the table of the speed cell")
    p.add_argument("--row", default="ssma", help="the row (network) of the speed cell")
    p.add_argument("--size", default="1024x2048", help="HEIGHTxWIDTH")
    p.add_argument("--settings", default="default,no-arena,no-pattern,neither")
    p.add_argument("--mode", choices=("fresh", "interleave"), default="fresh")
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--warmup", type=int, default=2)
    p.add_argument("--passes", type=int, default=3)
    p.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    p.add_argument("--one", choices=sorted(SETTINGS), help=argparse.SUPPRESS)
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    if args.one:
        args.setting = args.one
        print(json.dumps(one_process(args)))
        return 0
    settings = args.settings.split(",")
    unknown = sorted(set(settings) - set(SETTINGS))
    if unknown:
        p.error(f"unknown settings {unknown}; known: {', '.join(SETTINGS)}")
    from evsmap.environment import instruction_set

    result = {"cell": f"{args.table}/{args.row}", "size": args.size, "threads": args.threads,
              "mode": args.mode, "instruction_set": instruction_set(),
              "load_before": os.getloadavg(),
              **(fresh(args, settings) if args.mode == "fresh"
                 else interleave(args, settings)),
              "load_after": os.getloadavg()}
    text = json.dumps(result, indent=1)
    if args.json:
        args.json.write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
