"""Fuzz targets' session: the hypothesis profile (``EVSMAP_FUZZ_PROFILE``: ``ci`` by default,
``fuzz`` under ``nox -s fuzz``) and, at the end, the examples run per target (printed, and
written as JSON to ``EVSMAP_FUZZ_REPORT`` when set)."""

from __future__ import annotations

import json
import os
from pathlib import Path

from tests.fuzz.harness import CASES, FAILURES, MEMORY_BOUND, load_profile

PROFILE = load_profile()


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    if not CASES:
        return
    tr = terminalreporter
    tr.section(f"fuzz targets ({PROFILE})")
    for target in sorted(CASES):
        tr.write_line(f"{target:<36} {CASES[target]:>7} examples  "
                      f"{FAILURES.get(target, 0):>4} failing")
    tr.write_line(f"{'total':<36} {sum(CASES.values()):>7} examples")
    report = os.environ.get("EVSMAP_FUZZ_REPORT")
    if report:
        Path(report).parent.mkdir(parents=True, exist_ok=True)
        Path(report).write_text(json.dumps({
            "profile": PROFILE, "memory_bound_bytes": MEMORY_BOUND,
            "targets": {t: {"examples": CASES[t], "failing": FAILURES.get(t, 0)}
                        for t in sorted(CASES)}}, indent=1))
