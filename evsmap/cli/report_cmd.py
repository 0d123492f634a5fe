"""``evsmap report``: rebuild a run folder's report from its stored records."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "report", help="rebuild the report of a run folder from its stored records",
        description="Read DIR/run.json and DIR/records/*.json written by 'evsmap reproduce' and "
                    "write the tables (tableN.md/.csv, extra.csv), the figures and index.md "
                    "into DIR. Nothing is measured.")
    p.add_argument("dir", type=Path, metavar="DIR", help="run folder (reports/<run>)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from evsmap.report.build import build_report

    for path in build_report(args.dir):
        print(path)
    return 0
