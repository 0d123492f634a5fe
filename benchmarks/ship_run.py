"""Ship finished ``evsmap reproduce`` runs into ``results/``: each run's ``run.json`` and
``records/*.json`` (not its cache, artifacts or rendered report), in a folder named by the
machine and the commit, and the listing in ``results/README.md`` made again::

    python benchmarks/ship_run.py reports/full reports/quick
    python benchmarks/ship_run.py reports/full --commit 111188e   # a run whose commit is unknown

The folder is ``<cpu>_<instruction set>_<cores>c[_<gpu>]_<kind>_<commit>_<full|quick>``: the
CPU's model, its widest vector instruction set and its cores, the GPU's model where the run's
cells ran on one, the machine kind (:func:`evsmap.gate.baseline.machine_kind`: a digest of the
CPU, its vector features, the cores, Python and the timing libraries' versions), the first ten
digits of evsmap's commit (from ``run.json``'s environment, else ``--commit``) and whether the
run was ``--quick``. ``evsmap report results/<folder>`` rebuilds its report with today's code;
``evsmap compare results/<a> results/<b>`` sets two side by side. An interrupted run (no
``finished``) is refused; an existing folder too unless ``--overwrite``. Errors: one line, exit 2.
"""

from __future__ import annotations

import argparse
import re
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
LISTING_START = "<!-- shipped runs -->"
LISTING_END = "<!-- shipped runs end -->"
RESULTS_IGNORED = re.compile(r"^(index\.md|tables?\d*\.(md|csv|tex)|extra\.csv|int8\.csv"
                             r"|.*\.png)$")
"""What ``evsmap report`` writes beside a shipped run's data (results/.gitignore keeps it out of
git): not part of the shipped run."""


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9.]+", "-", text.lower()).strip("-") or "unknown"


def run_environment(loaded: Any) -> dict[str, Any]:
    """The run's environment, with the GPU's facts (from a GPU cell's record) where its cells
    ran on a GPU."""
    from evsmap.report.run_data import gpu_of

    env = dict(loaded.environment)
    if gpu_of(loaded.run) and not isinstance(env.get("gpu"), dict):
        for rec in loaded.records:
            facts = (rec.details or {}).get("gpu")
            if rec.status == "ok" and isinstance(facts, dict) and facts.get("gpu"):
                env["gpu"] = facts
                break
    return env


def folder_name(loaded: Any, commit: str | None = None) -> str:
    """The shipped folder's name (module docstring)."""
    from evsmap.errors import EvsmapError
    from evsmap.gate.baseline import machine_kind
    from evsmap.report.run_data import commit_of, gpu_of

    env = run_environment(loaded)
    commit = commit or commit_of(loaded.run)
    if commit == "unknown":
        raise EvsmapError(f"{loaded.path}: run.json names no commit; give the one it ran "
                         f"(--commit SHA)")
    gpu = gpu_of(loaded.run)
    parts = [_slug(str(env.get("cpu") or "cpu")), _slug(str(env.get("instruction_set") or "")),
             f"{env.get('cpus') or 0}c", *([_slug(gpu)] if gpu else []), machine_kind(env),
             commit.replace("+dirty", "")[:10] + ("-dirty" if "+dirty" in commit else ""),
             "quick" if loaded.run.get("quick") else "full"]
    return "_".join(parts)


def ship(run_dir: Path, results: Path = RESULTS, *, commit: str | None = None,
         overwrite: bool = False) -> Path:
    """Copy ``run_dir``'s ``run.json`` and records into ``results/<folder_name>``, whole (a
    staging folder renamed into place); returns the folder."""
    from evsmap.errors import EvsmapError
    from evsmap.fileio import staging_folder
    from evsmap.report.run_data import load_run

    loaded = load_run(run_dir)
    if not loaded.run.get("finished"):
        raise EvsmapError(f"{run_dir}: the run did not finish (run.json has no 'finished'); "
                          f"ship a complete run (`evsmap reproduce --resume --out {run_dir}`)")
    if not loaded.records:
        raise EvsmapError(f"{run_dir}: the run has no records to ship")
    target = results / folder_name(loaded, commit)
    if target.exists() and not overwrite:
        raise EvsmapError(f"{target}: already shipped (pass --overwrite to replace it)")
    with staging_folder(target, overwrite=overwrite, what="") as stage:
        shutil.copy2(run_dir / "run.json", stage / "run.json")
        (stage / "records").mkdir()
        for path in sorted((run_dir / "records").glob("*.json")):
            shutil.copy2(path, stage / "records" / path.name)
    return target


def shipped(results: Path = RESULTS) -> list[Path]:
    """Every shipped run folder under ``results`` (a folder with a ``run.json``), by name."""
    return sorted(p.parent for p in results.glob("*/run.json"))


def listing(results: Path = RESULTS) -> str:
    """The Markdown table of the shipped runs (results/README.md's listing)."""
    from evsmap.report.run_data import commit_of, load_run, machine_text

    lines = [LISTING_START, "",
             "| folder | machine | commit | run | started | cells measured |",
             "|---|---|---|---|---|---:|"]
    for folder in shipped(results):
        loaded = load_run(folder)
        ok = sum(1 for r in loaded.records if r.status == "ok")
        lines.append(f"| [`{folder.name}`]({folder.name}) | {machine_text(loaded.run)} | "
                     f"`{commit_of(loaded.run)[:10]}` | "
                     f"{'quick' if loaded.run.get('quick') else 'full'} | "
                     f"{str(loaded.run.get('started') or '')[:16]} | "
                     f"{ok} of {len(loaded.records)} |")
    return "\n".join([*lines, "", LISTING_END])


def update_readme(results: Path = RESULTS) -> Path:
    """Write the listing between the markers of ``results/README.md``."""
    from evsmap.errors import EvsmapError
    from evsmap.fileio import atomic_write_text

    readme = results / "README.md"
    text = readme.read_text()
    start, end = text.find(LISTING_START), text.find(LISTING_END)
    if start < 0 or end < start:
        raise EvsmapError(f"{readme}: no '{LISTING_START}' ... '{LISTING_END}' section")
    atomic_write_text(readme, text[:start] + listing(results) + text[end + len(LISTING_END):])
    return readme


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+", metavar="RUN_DIR",
                        help="a finished run folder (evsmap reproduce --out)")
    parser.add_argument("--results", type=Path, default=RESULTS, metavar="DIR",
                        help="where the shipped runs live (default: the repository's results/)")
    parser.add_argument("--commit", default=None, metavar="SHA",
                        help="the evsmap commit the run measured, where run.json names none")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace a run shipped before under the same name")
    args = parser.parse_args(argv)
    from evsmap.errors import EvsmapError

    try:
        for run_dir in args.runs:
            print(ship(run_dir, args.results, commit=args.commit, overwrite=args.overwrite))
        print(update_readme(args.results))
    except EvsmapError as exc:
        print(f"ship_run: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
