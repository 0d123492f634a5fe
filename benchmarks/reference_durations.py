"""Write ``evsmap/runner/reference_durations.json`` (``reference_durations_quick.json`` for a
``--quick`` run) from a finished ``evsmap reproduce`` run:
how long the run spent on each cell on that machine (a timed cell's whole wait, its process's
start-up included: :func:`evsmap.runner.estimate.cell_duration`) and outside its cells (from
``run.json``'s ``time_accounting``), with the machine's calibration, so that a new user's first
run can estimate its time (:mod:`evsmap.runner.estimate` scales these by the two
machines' calibrations).

Use a first run with an empty cache (``EVSMAP_CACHE_DIR`` pointing at an empty folder), on an
idle machine, so the durations include what a new user pays (exports, renders, counts), and a
second run in the same cache (``--warm``: what later runs pay, kept in the file's ``warm``
section)::

    export EVSMAP_CACHE_DIR=$(mktemp -d)
    evsmap reproduce --out reports/ref && evsmap reproduce --out reports/ref-warm
    python benchmarks/reference_durations.py reports/ref --warm reports/ref-warm
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from evsmap.fileio import atomic_write_text
from evsmap.report.build import read_records
from evsmap.runner.estimate import REFERENCE_FILES, cell_duration


def durations(folder: Path) -> tuple[dict[str, Any], dict[str, float], dict[str, Any] | None]:
    """A run folder's ``run.json``, its measured cells' durations and its time outside them."""
    run = json.loads((folder / "run.json").read_text())
    cells = {r.key: round(cell_duration(r), 2) for r in read_records(folder)
             if r.status == "ok" and r.seconds > 0}
    accounting = run.get("time_accounting") or {}
    outside = ({"seconds": round(accounting["wall_s"] - sum(cells.values()), 2),
                "cells": len(cells)} if accounting.get("wall_s") else None)
    return run, cells, outside


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="the first run's folder (an empty cache)")
    parser.add_argument("--warm", type=Path, default=None,
                        help="a second run's folder, same machine and cache")
    parser.add_argument("--fill", type=Path, nargs=2, default=None, metavar=("FIRST", "SECOND"),
                        help="an earlier pair of runs (first, second) on the same kind of "
                             "machine whose cells the runs above lack (e.g. the TUM sample's, "
                             "when they ran without it) fill the gaps")
    args = parser.parse_args()
    run, cells, outside = durations(args.run)
    fill_first, fill_second = ((durations(f)[1] for f in args.fill) if args.fill
                               else ({}, {}))
    filled = sorted(set(fill_first) - set(cells))
    cells.update({k: fill_first[k] for k in filled})
    calibration = json.loads((args.run / "cache" / "calibration.json").read_text())
    env = run.get("environment") or {}
    data: dict[str, Any] = {
        "machine": {"cpu": env.get("cpu"), "instruction_set": env.get("instruction_set"),
                    "threads": env.get("threads"),
                    "calibration_gmacs": round(float(calibration["best_gmacs"]), 2)},
        "run": {"started": run.get("started"), "finished": run.get("finished"),
                "git_commit": env.get("git_commit"), "quick": run.get("quick"),
                "extended": (run.get("settings") or {}).get("extended")},
        "outside": outside, "cells": dict(sorted(cells.items()))}
    if filled:
        data["filled"] = {"from": [str(f) for f in args.fill], "cells": filled}
    if args.warm is not None:
        warm_run, warm_cells, warm_outside = durations(args.warm)
        warm_cells.update({k: fill_second[k] for k in filled if k in fill_second})
        if bool(warm_run.get("quick")) != bool(run.get("quick")):
            parser.error(f"{args.warm}: not the same kind of run as {args.run} (--quick)")
        data["warm"] = {"started": warm_run.get("started"), "outside": warm_outside,
                        "cells": dict(sorted(warm_cells.items()))}
    target = REFERENCE_FILES[bool(run.get("quick"))]
    atomic_write_text(target, json.dumps(data, indent=1) + "\n")
    print(f"{len(cells)} cells, {sum(cells.values()) / 60:.1f} min in them, "
          f"{(outside or {}).get('seconds', 0) / 60:.1f} min outside -> {target}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
