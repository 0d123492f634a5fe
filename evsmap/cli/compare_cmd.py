"""``evsmap compare``: two or more runs (or a run and the paper) side by side."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from evsmap.report.compare import Comparison

PAPER = "paper"
""":data:`evsmap.report.compare.PAPER` (named here: the report package imports pandas, and the
parser is built without it)."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "compare", help="set two or more runs (or a run and the paper) side by side",
        description="Read run folders written by 'evsmap reproduce' (reports/<run>, or the "
                    "shipped runs under results/) and print the cells they all measured, each "
                    "value with its precision (a timed one: its median +- the half-width of "
                    "its 95%% interval) and each run's ratio to the first with its own "
                    "precision (the two relative half-widths added); counts and sizes compared "
                    "exactly (equal / differ); the machines and commits at the top; the cells "
                    f"only some runs measured apart. '{PAPER}' names the paper's printed "
                    "figures as a run. Nothing is measured.")
    p.add_argument("runs", nargs="+", metavar="RUN",
                   help=f"run folder, or '{PAPER}' (the first is the one the ratios divide by)")
    p.add_argument("--paper", action="store_true",
                   help="add the paper's printed figures as the last column")
    p.add_argument("--json", action="store_true", help="print the comparison as JSON")
    p.add_argument("--format", choices=("markdown", "latex"), default="markdown",
                   help="what is printed (and written to compare.md or compare.tex): Markdown "
                        "(default) or LaTeX booktabs tables")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="also write compare.md, compare.csv, compare.json, compare.tex and "
                        "speed.png (each speed cell: run A's FPS against the others', log axes, "
                        "the diagonal, error bars from the precision) into DIR")
    p.add_argument("--overwrite", action="store_true",
                   help="replace a non-empty --out folder once the new one is complete")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from evsmap.cli.outputs import Output, claim_outputs

    if args.out is not None:
        claim_outputs([Output("--out", args.out, folder=True)], overwrite=args.overwrite)
    comparison = _compare(args.runs, paper=args.paper)
    from evsmap.report.compare_text import compare_json, compare_markdown

    if args.json:
        print(json.dumps(compare_json(comparison), indent=1))
    elif args.format == "latex":
        from evsmap.report.latex import compare_latex

        print(compare_latex(comparison), end="")
    else:
        print(compare_markdown(comparison), end="")
    if args.out is not None:
        for path in _write(comparison, args.out, overwrite=args.overwrite):
            print(path)
    return 0


def _compare(runs: list[str], *, paper: bool) -> Comparison:
    """The comparison, each run's machine kind (:func:`evsmap.gate.baseline.machine_kind`, the
    gate's id of what a timing depends on) stated beside its machine."""
    from evsmap.gate.baseline import machine_kind
    from evsmap.report.compare import compare_columns, read_columns

    columns = read_columns(runs, paper=paper)
    for column in columns:
        if column.environment:
            column.kind = machine_kind(column.environment)
    return compare_columns(columns)


def _write(comparison: Comparison, out: Path, *, overwrite: bool) -> list[Path]:
    from evsmap.fileio import staging_folder
    from evsmap.report.compare_plot import speed_plot
    from evsmap.report.compare_text import compare_frame, compare_json, compare_markdown
    from evsmap.report.latex import PACKAGES, compare_latex

    names = []
    with staging_folder(out, overwrite=overwrite, what="--out ") as stage:
        (stage / "compare.md").write_text(compare_markdown(comparison))
        compare_frame(comparison).to_csv(stage / "compare.csv", index=False)
        (stage / "compare.json").write_text(json.dumps(compare_json(comparison), indent=1)
                                            + "\n")
        (stage / "compare.tex").write_text(
            "% needs \\usepackage{" + ",".join(PACKAGES) + "}\n" + compare_latex(comparison))
        names = ["compare.md", "compare.csv", "compare.json", "compare.tex"]
        if speed_plot(comparison, stage / "speed.png"):
            names.append("speed.png")
    return [out / name for name in names]
