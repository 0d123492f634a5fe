"""``evsmap report``: rebuild a run folder's report from its stored records."""

from __future__ import annotations

import argparse
import errno
from pathlib import Path

from evsmap.errors import EvsmapError


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "report", help="rebuild the report of a run folder from its stored records",
        description="Read DIR/run.json and DIR/records/*.json written by 'evsmap reproduce' and "
                    "write the tables (tableN.md/.csv, extra.csv), the figures and index.md "
                    "into DIR. Nothing is measured.")
    p.add_argument("dir", type=Path, metavar="DIR",
                   help="run folder (reports/<run>, or a shipped run under results/)")
    p.add_argument("--format", choices=("markdown", "latex"), default="markdown",
                   help="markdown (default): the whole report; latex: Tables I-IV as booktabs "
                        "tables, tableN.tex, and tables.tex, a document that inputs them")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from evsmap.report.build import build_latex, build_report

    if args.dir.exists() and not args.dir.is_dir():
        raise EvsmapError(f"{args.dir}: is a file, not a run folder (give the folder "
                          "`evsmap reproduce --out` wrote, with run.json in it)")
    try:
        written = (build_latex(args.dir) if args.format == "latex"
                   else build_report(args.dir))
    except OSError as exc:
        # a report file whose place is taken by a folder (or a folder by a file): one line
        # naming it; the files written before it are complete (each is written by rename)
        if exc.errno not in (errno.EISDIR, errno.ENOTDIR, errno.ENOTEMPTY, errno.EEXIST):
            raise
        target = exc.filename2 if exc.filename2 is not None else exc.filename
        raise EvsmapError(f"{target}: cannot write the report file there ({exc.strerror}): "
                          "move that away and run the command again") from None
    for path in written:
        print(path)
    return 0
