"""The paired gate (``evsmap gate --against REF``): a reference commit measured beside this tree
in the same run, so no stored figure from another machine is needed.

1. The reference commit's files are written into a temporary folder (``git archive``: the
   repository's own state is not touched) and its side prepared by its own code
   (``python -m evsmap.gate.prepare``): its ONNX exports, its observations, its workloads.
2. It runs with this interpreter and these libraries, its folder first on the import path,
   when its dependencies are this tree's (the lock ``constraints.txt`` and ``pyproject.toml``'s
   dependencies, extras and entry points); otherwise in its own virtual environment built from
   its own lock (cached by the lock's digest), and the report says so.
3. Every workload both sides have runs as pairs of fresh processes on the same pinned CPU, the
   reference's and this tree's back to back, the order swapped from one pair to the next (A B,
   B A, ...) so neither side always runs second. The verdict comes from the paired ratios
   (:func:`evsmap.gate.compare.compare_paired`); a workload outside the band after the first
   pass gets ``confirm`` more pairs and is judged on the median of all.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import time
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from evsmap.errors import EvsmapError
from evsmap.gate.prepare import CONTEXT_FILE, PROTOCOL, missing_input, prepare, read_prepared
from evsmap.gate.run import THIS_TREE, Checkout, outside_band, run_worker
from evsmap.gate.workloads import Workload

PREPARE_TIMEOUT_S = 1800
Pairs = dict[str, list[tuple[dict[str, Any], dict[str, Any]]]]


@dataclass
class Side:
    """One side of a paired run: its ``checkout`` (how its processes start), the ``context``
    and ``workloads`` its own code prepared in ``workdir``."""

    label: str
    checkout: Checkout
    workdir: Path
    context: dict[str, Any]
    workloads: dict[str, Workload]

    @property
    def context_file(self) -> Path:
        return self.workdir / CONTEXT_FILE


@dataclass
class PairedRun:
    """What a paired run measured: ``pairs`` (workload -> (reference, this tree) records),
    the workloads only one side has, how the reference ran (``environment``) and its commit."""

    commit: str
    environment: str
    pairs: Pairs = field(default_factory=dict)
    only_here: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    only_reference: list[str] = field(default_factory=list)


# -- the reference's environment -----------------------------------------------------------------


def dependency_digest(root: Path) -> str:
    """A digest of what a checkout installs: its lock file's bytes and ``pyproject.toml``'s
    dependencies, extras, entry points, scripts and build system."""
    h = hashlib.sha256()
    lock = root / "constraints.txt"
    h.update(lock.read_bytes() if lock.is_file() else b"no lock")
    pyproject = root / "pyproject.toml"
    if pyproject.is_file():
        try:
            data = tomllib.loads(pyproject.read_text())
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise EvsmapError(f"{pyproject}: not readable TOML ({exc})") from None
        project = data.get("project", {})
        picked = {k: project.get(k) for k in ("dependencies", "optional-dependencies",
                                               "entry-points", "scripts", "requires-python")}
        picked["build-system"] = data.get("build-system")
        h.update(json.dumps(picked, sort_keys=True, default=str).encode())
    return h.hexdigest()[:16]


def _pinned_torch(lock: Path) -> str | None:
    if not lock.is_file():
        return None
    for line in lock.read_text().splitlines():
        if line.strip().startswith("torch=="):
            return line.strip().split()[0]
    return None


def own_environment(source: Path, digest: str, log: Callable[[str], Any]) -> str:
    """The interpreter of a virtual environment with ``source`` installed from its own lock
    (``pip install -c constraints.txt``; torch first and alone, as the noxfile does, so no
    resolver step picks a CUDA build), made once per lock digest under evsmap's cache.

    Raises:
        EvsmapError: the environment could not be built (pip's last line).
    """
    from evsmap.cache import cache_dir

    venv = cache_dir("gate") / "envs" / digest
    python = venv / "bin" / "python"
    if (venv / ".complete").exists():
        return str(python)
    log(f"building the reference's own environment in {venv} (its lock differs from this "
        f"tree's); made once per lock")
    lock = source / "constraints.txt"
    constraints = ["-c", str(lock)] if lock.is_file() else []
    steps = [[sys.executable, "-m", "venv", "--clear", str(venv)]]
    torch = _pinned_torch(lock)
    if torch:
        steps.append([str(python), "-m", "pip", "install", "-q", *constraints, torch])
    steps.append([str(python), "-m", "pip", "install", "-q", *constraints, str(source)])
    for cmd in steps:
        proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if proc.returncode != 0:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["failed"]
            raise EvsmapError(f"cannot build the reference's environment ({' '.join(cmd[2:4])}"
                              f"): {tail[0]}")
    (venv / ".complete").write_text("")
    return str(python)


def reference_checkout(source: Path, here: Path, commit: str,
                       log: Callable[[str], Any]) -> tuple[Checkout, str]:
    """How the reference's processes start, and a sentence saying so."""
    from evsmap.cache import CACHE_ENV, cache_dir
    from evsmap.paths import DATA_ROOT_ENV, default_data_root

    env = {DATA_ROOT_ENV: str(default_data_root()),  # the samples this tree's side reads
           # the reference's ONNX exports and other caches apart from this tree's
           CACHE_ENV: str(cache_dir("gate") / "reference" / commit[:12]),
           "PYTHONPATH": os.pathsep.join([str(source), *filter(None, [
               os.environ.get("PYTHONPATH")])])}
    theirs, ours = dependency_digest(source), dependency_digest(here)
    if theirs == ours:
        return (Checkout(python=sys.executable, cwd=source, env=env),
                "this interpreter and libraries (its lock and dependencies are this tree's), "
                "its own source first on the import path")
    python = own_environment(source, theirs, log)
    return (Checkout(python=python, cwd=source, env=env),
            f"its own virtual environment, built from its lock (its dependencies differ from "
            f"this tree's): {python}")


def prepare_reference(checkout: Checkout, workdir: Path, *, threads: int, cpu: int,
                      patterns: Sequence[str] | None, commit: str) -> Side:
    """The reference's side, prepared by its own code in a process of its own.

    Raises:
        EvsmapError: the reference has no ``evsmap.gate.prepare`` (it predates the paired gate)
            or its preparation failed.
    """
    workdir.mkdir(parents=True, exist_ok=True)
    cmd = [checkout.python, "-m", "evsmap.gate.prepare", "--workdir", str(workdir),
           "--threads", str(threads), "--cpu", str(cpu)]
    if patterns:
        cmd += ["--only", *patterns]
    proc = subprocess.run(cmd, cwd=checkout.cwd, env={**os.environ, **checkout.env},
                          capture_output=True, text=True, timeout=PREPARE_TIMEOUT_S,
                          check=False)
    if "No module named evsmap.gate.prepare" in proc.stderr:
        raise EvsmapError(f"--against {commit[:12]}: that commit predates the paired gate (no "
                          f"evsmap.gate.prepare): name a later one")
    if proc.returncode != 0:
        tail = proc.stderr.strip().splitlines()[-1:] or [f"exit {proc.returncode}"]
        raise EvsmapError(f"--against {commit[:12]}: preparing the reference failed: {tail[0]}")
    context, workloads = read_prepared(workdir)
    if context.get("protocol") != PROTOCOL:
        raise EvsmapError(f"--against {commit[:12]}: its gate speaks protocol "
                          f"{context.get('protocol')}, this tree's {PROTOCOL}: name a commit "
                          f"with the same gate protocol")
    return Side("reference", checkout, workdir, context, {w.name: w for w in workloads})


# -- measuring ------------------------------------------------------------------------------------


def _run(side: Side, name: str, *, budget_s: float) -> dict[str, Any]:
    why = missing_input(side.workloads[name], side.context)
    if why:
        return {"name": name, "skipped": why}
    out = side.workdir / "records"
    out.mkdir(exist_ok=True)
    t0 = time.perf_counter()
    record = run_worker(side.workloads[name], side.context_file, out, budget_s=budget_s,
                        threads=int(side.context["threads"]), checkout=side.checkout)
    record["seconds"] = time.perf_counter() - t0
    return record


def measure_pairs(names: Sequence[str], reference: Side, here: Side, *, rounds: int,
                  first_round: int = 0, budget_s: float,
                  progress: bool = True) -> Pairs:
    """``rounds`` pairs of processes per workload, in rounds (every workload's pair, then the
    next round), the reference first in even rounds and this tree first in odd ones. A
    workload this tree cannot run (missing data) is not run on the reference either."""
    from tqdm import tqdm

    pairs: Pairs = {}
    jobs = [(r, n) for r in range(first_round, first_round + rounds) for n in names]
    bar = tqdm(total=2 * len(jobs), desc="gate (paired)", unit="process", file=sys.stderr,
               disable=not progress, leave=False)
    for r, name in jobs:
        bar.set_postfix_str(name)
        why = missing_input(here.workloads[name], here.context)
        if why:  # neither side runs it
            skipped = {"name": name, "skipped": why}
            pairs.setdefault(name, []).append((skipped, skipped))
            bar.update(2)
            continue
        order = (reference, here) if r % 2 == 0 else (here, reference)
        records = {}
        for side in order:
            records[side.label] = _run(side, name, budget_s=budget_s)
            bar.update(1)
        pairs.setdefault(name, []).append((records["reference"], records["here"]))
    bar.close()
    return pairs


def paired_gate(*, source_root: Path, commit: str, patterns: Sequence[str] | None,
                threads: int, cpu: int, budget_s: float, rounds: int, confirm: int,
                workdir: Path, progress: bool = True,
                log: Callable[[str], Any] = lambda _: None) -> PairedRun:
    """Measure ``commit`` (of the checkout at ``source_root``) beside this tree: see the module
    docstring. Returns the records; :func:`evsmap.gate.compare.compare_paired` judges them.

    Raises:
        EvsmapError: the reference cannot be checked out, installed or prepared.
    """
    from evsmap.gate.compare import compare_paired
    from evsmap.gitinfo import export_tree

    source = workdir / "reference-source"
    log(f"reference: commit {commit[:12]}, its files written to {source}")
    export_tree(source_root, commit, source)
    checkout, environment = reference_checkout(source, source_root, commit, log)
    log(f"reference runs with {environment}")
    log("preparing this tree's side")
    context, chosen = prepare(workdir / "here", threads=threads, cpu=cpu, patterns=patterns,
                              log=log)
    here = Side("here", THIS_TREE, workdir / "here", context, {w.name: w for w in chosen})
    log("preparing the reference's side (its own code: its ONNX exports, its observations)")
    reference = prepare_reference(checkout, workdir / "reference", threads=threads, cpu=cpu,
                                  patterns=patterns, commit=commit)
    run = PairedRun(commit=commit, environment=environment)
    both = [w.name for w in chosen if w.name in reference.workloads]
    run.only_reference = sorted(set(reference.workloads) - set(here.workloads))
    log(f"measuring {len(both)} workloads in pairs of fresh processes (the reference's and "
        f"this tree's) on CPU {cpu}, {rounds} pair{'s' if rounds > 1 else ''} each")
    run.pairs = measure_pairs(both, reference, here, rounds=rounds, budget_s=budget_s,
                              progress=progress)
    for name in (n for n in here.workloads if n not in reference.workloads):
        run.only_here[name] = [_run(here, name, budget_s=budget_s)]
    if confirm > 0:
        doubtful = [w.name for w in outside_band(compare_paired(run.pairs),
                                                 [here.workloads[n] for n in both])]
        if doubtful:
            log(f"{len(doubtful)} workload{'s' if len(doubtful) > 1 else ''} outside the band "
                f"after the first pass, measured in {confirm} more pairs: "
                f"{', '.join(doubtful)}")
            more = measure_pairs(doubtful, reference, here, rounds=confirm,
                                 first_round=rounds, budget_s=budget_s, progress=progress)
            for name, extra in more.items():
                run.pairs[name] += extra
    return run
