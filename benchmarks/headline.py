"""Write the README's headline table ("What reproduces here") from shipped runs::

    python benchmarks/headline.py results/<full run> --write README.md

Without ``--write`` the section is printed. It is made by
:func:`evsmap.report.headline.headline_markdown` from the runs' records with today's code, between
the ``<!-- headline: RUN -->`` and ``<!-- headline end -->`` markers; tests/report/
test_headline_readme.py makes it again from the runs the marker names and checks that README.md
holds exactly that. Errors: one line, exit 2.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def section(names: Sequence[str], root: Path = ROOT) -> str:
    """The section for the runs ``names`` (paths relative to ``root``)."""
    from evsmap.report.headline import headline_markdown, load_runs

    return headline_markdown(load_runs(root, names), names)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", metavar="RUN",
                        help="shipped run folders (results/<folder>), relative to the repository")
    parser.add_argument("--write", type=Path, default=None, metavar="README",
                        help="replace the section between the markers of this file")
    args = parser.parse_args(argv)
    from evsmap.errors import EvsmapError
    from evsmap.fileio import atomic_write_text
    from evsmap.report.headline import replace_section

    names = [Path(n).resolve().relative_to(ROOT).as_posix() if Path(n).is_absolute()
             else Path(n).as_posix() for n in args.runs]
    try:
        text = section(names)
        if args.write is None:
            print(text, end="")
            return 0
        atomic_write_text(args.write, replace_section(args.write.read_text(), text))
    except (EvsmapError, ValueError, OSError) as exc:
        print(f"headline: {exc}", file=sys.stderr)
        return 2
    print(args.write)
    return 0


if __name__ == "__main__":
    sys.exit(main())
