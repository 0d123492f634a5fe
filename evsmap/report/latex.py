"""The paper's tables, and a comparison of runs, as LaTeX ``booktabs`` tables.

``evsmap report RUN --format latex`` writes ``tableN.tex`` per table of the run
(:func:`table_latex`) and ``tables.tex``, a document that inputs them (:func:`document`);
``evsmap compare ... --format latex`` writes the comparison (:func:`compare_latex`). Plain text,
no template engine; the tables need ``booktabs`` only.

Each table keeps the paper's layout: one row per system, and for every measured column the
value measured beside the paper's printed figure (the unit in the column's header; a timed value
as ``$0.283 \\pm 0.012$``, its median and the half-width of its 95 % interval). A cell that
was not measured reads ``n/a`` (``error``, ``--`` for a row evsmap does not implement) with a
lettered note below the table saying why; the caption names the machine and the commit. Text
from the tables and the records is escaped (:func:`escape`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import pandas as pd

from evsmap.report.cells import format_number, format_ratio, header_with_unit, number, row_label
from evsmap.report.compare import Comparison, Ratio, Value
from evsmap.report.run_data import LoadedRun, commit_of, machine_text
from evsmap.tables.schema import Cell, Column, PaperTable

_SPECIAL = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#",
            "_": r"\_", "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}",
            "^": r"\textasciicircum{}", "<": r"\textless{}", ">": r"\textgreater{}",
            "Δ": r"\ensuremath{\Delta}", "×": r"\ensuremath{\times}", "÷": r"\ensuremath{\div}",
            "±": r"\ensuremath{\pm}", "†": r"\textsuperscript{\dag}", "√": r"\ensuremath{\surd}",
            "≈": r"\ensuremath{\approx}", "–": "--", "—": "---", "’": "'", "µ": r"\ensuremath{\mu}"}
"""Characters LaTeX reads as commands (or a default engine cannot set) -> their escape."""

PACKAGES = ("booktabs",)
"""What the tables need in the preamble."""


def escape(text: Any) -> str:
    """``text`` with LaTeX's special characters escaped (``&``, ``%``, ``$``, ``#``, ``_``,
    braces, ``~``, ``^``, the backslash) and the symbols the tables use (Δ, ×, †, √, ±)
    written as commands."""
    return "".join(_SPECIAL.get(ch, ch) for ch in " ".join(str(text).split()))


class Notes:
    """Lettered table notes (a, b, ..., z, aa, ...); the same text gets the same letter."""

    def __init__(self) -> None:
        self.texts: list[str] = []

    def mark(self, text: str) -> str:
        text = " ".join(str(text).split())
        if not text:
            return ""
        if text not in self.texts:
            self.texts.append(text)
        return r"\textsuperscript{" + _letter(self.texts.index(text)) + "}"

    def latex(self) -> list[str]:
        if not self.texts:
            return []
        lines = [r"\par\smallskip", r"{\footnotesize"]
        lines += [r"\textsuperscript{" + _letter(i) + "}~" + escape(t) + r"\par"
                  for i, t in enumerate(self.texts)]
        return lines + ["}"]


def _letter(i: int) -> str:
    letters = ""
    i += 1
    while i:
        i, r = divmod(i - 1, 26)
        letters = chr(ord("a") + r) + letters
    return letters


def timed_text(value: float, rel: float | None, decimals: int | None) -> str:
    """``$0.283 \\pm 0.012$`` (the half-width at the value's digits), ``0.283`` without a
    precision."""
    text = format_number(value, decimals)
    if rel is None:
        return text
    digits = len(text.split(".")[1]) if "." in text else 0
    return f"${text} \\pm {abs(value) * rel:.{digits}f}$"


def _paper_latex(cell: Cell) -> str:
    if cell.number is None:
        return "--"
    text = escape(cell.printed_number) + "".join(escape(m) if m == "†" else
                                                 r"\textsuperscript{" + escape(m) + "}"
                                                 for m in cell.marks)
    return r"\textbf{" + text + "}" if cell.bold else text


def _measured_latex(line: Mapping[str, Any], cell: Cell, column: Column, notes: Notes) -> str:
    status = line["status"]
    note = str(line.get("note") or "")
    if status == "paper only":
        return "--" + notes.mark("evsmap does not implement this row (paper only).")
    if status == "ok":
        decimals = cell.decimals if cell.number is not None else None
        measured = float(line["measured"])
        rel = number(line.get("rel_ci")) if column.timing else None
        text = timed_text(measured, rel, decimals) if column.timing else \
            format_number(measured, decimals)
        flag = line.get("timing_flag")
        if isinstance(flag, str) and flag:
            text += notes.mark(f"timing flagged: {flag}")
        return text
    words = {"n/a": "n/a", "error": "error", "not run": "not run"}.get(status, "--")
    why = note.removeprefix("n/a - ") if note and note != "not run" else {
        "not run": "not run: the run has no record of this cell.",
        "no value": "the record holds no value for this column."}.get(status, status)
    return words + notes.mark(why)


def _caption(table: PaperTable, run: Mapping[str, Any]) -> str:
    quick = " (a \\texttt{--quick} run)" if run.get("quick") else ""
    started = str(run.get("started") or "")[:10]
    return (f"{escape(table.title)} (the paper's Table {escape(table.number)}). Measured by "
            f"evsmap on "
            f"{escape(machine_text(run))}, commit \\texttt{{{escape(commit_of(run)[:10])}}}"
            f"{quick}{', ' + escape(started) if started else ''}, beside the paper's figures; "
            f"a timed value is its median $\\pm$ the half-width of its 95\\,\\% interval.")


def table_latex(table: PaperTable, frame: pd.DataFrame, run: Mapping[str, Any]) -> str:
    """One paper table as a ``booktabs`` table: measured and paper side by side per column."""
    by_cell = {(r["row"], r["column"]): r for r in frame.to_dict("records")}
    notes = Notes()
    spans = [1 if c.kind == "flag" else 2 for c in table.columns]
    align = "l" + "".join("c" if s == 1 else "rr" for s in spans)
    head = ["System"]
    rules, sub = [], [""]
    at = 2
    for col, span in zip(table.columns, spans, strict=True):
        title = escape(header_with_unit(col))
        if span == 1:
            head.append(title)
            sub.append("")
        else:
            head.append(f"\\multicolumn{{2}}{{c}}{{{title}}}")
            rules.append(f"\\cmidrule(lr){{{at}-{at + 1}}}")
            sub += ["measured", "paper"]
        at += span
    body = []
    for system in table.rows:
        cells = [escape(row_label(system))]
        for col in table.columns:
            cell = table.cell(system.id, col.id)
            if col.kind == "flag":
                cells.append(escape(cell.printed) if cell.printed.strip() else "")
                continue
            line = by_cell.get((system.id, col.id))
            measured = ("--" if line is None else _measured_latex(line, cell, col, notes))
            cells += [measured, _paper_latex(cell)]
        body.append(" & ".join(cells) + r" \\")
    marks = [f"{escape(m)}: {escape(t.rstrip('. '))}" for m, t in table.footnotes.items()]
    out = [r"\begin{table}[htbp]", r"\centering", r"\small",
           f"\\caption{{{_caption(table, run)}}}", f"\\label{{tab:evsmap-{table.id}}}",
           f"\\begin{{tabular}}{{{align}}}", r"\toprule", " & ".join(head) + r" \\"]
    if rules:
        out += [" ".join(rules), " & ".join(sub) + r" \\"]
    out += [r"\midrule", *body, r"\bottomrule", r"\end{tabular}"]
    out += notes.latex()
    if marks:
        out += [r"{\footnotesize Marks as printed in the paper: " + "; ".join(marks) + r".\par}"]
    out.append(r"\end{table}")
    return "\n".join(out) + "\n"


def report_latex(loaded: LoadedRun) -> dict[str, str]:
    """``tableN.tex`` text per table of the run."""
    return {f"{tid}.tex": table_latex(loaded.tables[tid], loaded.frames[tid], loaded.run)
            for tid in loaded.table_ids}


def document(inputs: list[str], title: str) -> str:
    """A LaTeX document that inputs ``inputs`` (the ``.tex`` files beside it): what compiles
    the tables alone (``pdflatex tables.tex``)."""
    body = "\n".join(f"\\input{{{name}}}" for name in inputs)
    return ("\\documentclass[10pt]{article}\n\\usepackage[margin=1.5cm,landscape]{geometry}\n"
            + "".join(f"\\usepackage{{{p}}}\n" for p in PACKAGES)
            + f"\\title{{{escape(title)}}}\n\\date{{}}\n\\begin{{document}}\n\\maketitle\n"
            + body + "\n\\end{document}\n")


# ------------------------------------------------------------------------------- compare
def _value_latex(value: Value | None, timed: bool) -> str:
    if value is None:
        return "--"
    if value.decimals is not None:  # the paper's figure, as printed
        return f"{value.value:.{value.decimals}f}"
    return timed_text(value.value, value.rel if timed else None, None)


def _ratio_latex(ratio: Ratio) -> str:
    if ratio.ratio is None:
        return "--"
    text = "$" + format_ratio(ratio.ratio).removesuffix("x") + r"\times$"
    if ratio.rel is not None:
        text += f" ($\\pm${100 * ratio.rel:.1f}\\,\\%)"
    return f"{text} {escape(ratio.verdict)}"


def compare_latex(comparison: Comparison) -> str:
    """The shared cells of a comparison, one ``booktabs`` table per source table: every run's
    value and each run's ratio to the first; the runs' machines and commits in the caption."""
    cols = comparison.columns
    names = [chr(ord("A") + i) for i in range(len(cols))]
    who = "; ".join(f"{n}: {escape(c.name)} ({escape(c.machine)}, commit "
                    f"\\texttt{{{escape(c.commit[:10])}}})" for n, c in zip(names, cols,
                                                                            strict=True))
    groups: dict[str, list[str]] = {}
    for cid in comparison.shared:
        groups.setdefault(comparison.cells[cid].table, []).append(cid)
    from evsmap.tables.schema import load_tables

    titles = {tid: f"Table {t.number}" for tid, t in load_tables().items()}
    out = []
    for table, cids in groups.items():
        title = titles.get(table, "the mapping runs beyond the tables")
        head = ["System", "Column", *names, *(f"{n} / A" for n in names[1:])]
        out += [r"\begin{table}[htbp]", r"\centering", r"\small",
                f"\\caption{{Cells measured in every run, {escape(title)}. {who}. A timed "
                f"value is its median $\\pm$ the half-width of its 95\\,\\% interval; a ratio "
                f"of two carries both relative half-widths added.}}",
                f"\\label{{tab:evsmap-compare-{escape(table)}}}",
                "\\begin{tabular}{ll" + "r" * len(cols) + "l" * (len(cols) - 1) + "}",
                r"\toprule", " & ".join(head) + r" \\", r"\midrule"]
        for cid in cids:
            cell = comparison.cells[cid]
            values = [_value_latex(c.values.get(cid), cell.timed) for c in cols]
            ratios = [_ratio_latex(r) for r in comparison.ratios[cid]]
            out.append(" & ".join([escape(cell.label), escape(cell.header), *values, *ratios])
                       + r" \\")
        out += [r"\bottomrule", r"\end{tabular}", r"\end{table}", ""]
    return "\n".join(out)
