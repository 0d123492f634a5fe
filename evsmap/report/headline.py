"""The README's headline table: what of the paper reproduces, from shipped runs.

:func:`headline_markdown` is the section between :data:`START` and :data:`END` in README.md:
for each run given (a shipped run under ``results/``), each of the paper's claims with the
paper's figure, the run's, the verdict and the machine, as the run's ``index.md`` checks them
(:mod:`evsmap.report.claims`; the map-size claim in Table IV's reading only, the others are in
the run's index). ``python benchmarks/headline.py RUN ... --write README.md`` writes it;
:func:`replace_section` puts it between the markers and :func:`section_runs` reads back which
runs it was made from, so a test can make it again and find it equal.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

from evsmap.report.claims import checked_claims, claim_rows
from evsmap.report.run_data import LoadedRun, commit_of, machine_text

START = "<!-- headline: {runs} -->"
"""The section's first line: the runs it was made from, space-separated paths relative to the
README's folder."""
END = "<!-- headline end -->"
_START_RE = re.compile(r"^<!-- headline: (?P<runs>.+?) -->$", re.MULTILINE)

COMMAND = "python benchmarks/headline.py {runs} --write README.md"
"""The command that writes the section (in the section, so a reader can make it again)."""

WHY_LIMIT = 110
"""A verdict's reason is cut to this many characters in the README (the run's index.md has it
whole)."""


def headline_rows(loaded: LoadedRun) -> list[tuple[str, str, str, str, str]]:
    """(claim, paper, ours, verdict, machine) per claim of one run."""
    from evsmap.runner.table4_reading import TABLE4_READING

    machine = machine_text(loaded.run)
    rows = claim_rows(checked_claims(loaded.frames), loaded.extras, loaded.detail,
                      readings=(TABLE4_READING,))
    out = []
    for claim, measured, precision, paper, verdict in rows:
        ours = measured if precision in ("-", "exact") or measured == "-" else \
            f"{measured} {precision}"
        out.append((claim, paper, ours, _cut(verdict), machine))
    return out


def _cut(text: str) -> str:
    """``text`` cut to :data:`WHY_LIMIT` characters (a code span cut open is closed)."""
    if len(text) <= WHY_LIMIT:
        return text
    cut = text[:WHY_LIMIT - 4].rstrip()
    return cut + ("`" if cut.count("`") % 2 else "") + "...)"


def headline_markdown(runs: Sequence[LoadedRun], names: Sequence[str]) -> str:
    """The section (markers included) for ``runs``, named in it by ``names`` (their paths as
    the README links them)."""
    joined = " ".join(names)
    out = [START.format(runs=joined), ""]
    for run, name in zip(runs, names, strict=True):
        kind = "a `--quick` run" if run.run.get("quick") else "a full run"
        out.append(f"From [`{name}`]({name}) ({kind} of commit "
                   f"`{commit_of(run.run)[:10]}` on {machine_text(run.run)}, "
                   f"{str(run.run.get('started') or '')[:10]}).")
    out += ["", "Each claim is a ratio of two systems measured the same way on one machine (it "
            "carries across machines where absolute figures do not); a ratio of two timings "
            "is followed by its precision, the two timings' relative half-widths added. "
            "Written by `" + COMMAND.format(runs=joined) + "`; each run's `index.md` "
            "(`evsmap report RUN`) gives every reading and reason whole.", "",
            "| claim | paper | ours | verdict | machine |", "|---|---:|---:|---|---|"]
    for run in runs:
        out += ["| " + " | ".join(row) + " |" for row in headline_rows(run)]
    out += ["", END]
    return "\n".join(out) + "\n"


def section_runs(text: str) -> list[str] | None:
    """The runs the README's section was made from (None: no section)."""
    match = _START_RE.search(text)
    return None if match is None else match.group("runs").split()


def replace_section(text: str, section: str) -> str:
    """``text`` with its section (from the start marker to :data:`END`) replaced by
    ``section``.

    Raises:
        ValueError: ``text`` has no complete section to replace.
    """
    match = _START_RE.search(text)
    end = text.find(END, match.end()) if match else -1
    if match is None or end < 0:
        raise ValueError(f"no section between '<!-- headline: RUN -->' and '{END}'")
    return text[:match.start()] + section.rstrip("\n") + text[end + len(END):]


def load_runs(root: Path, names: Sequence[str]) -> list[LoadedRun]:
    """The runs ``names`` (relative to ``root``), read."""
    from evsmap.report.run_data import load_run

    return [load_run(root / name) for name in names]
