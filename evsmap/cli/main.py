"""The ``evsmap`` command line.

User errors (:class:`evsmap.errors.EvsmapError`, bad options) print one line on stderr and exit
with status 2; Ctrl-C exits with 130. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from evsmap.errors import EvsmapError


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump) and exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        sys.stderr.write(f"{self.prog}: error: {message} (see --help)\n")
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    from evsmap.cli import (
        cache_cmd,
        complexity_cmd,
        datasets_cmd,
        eval_cmd,
        gate_cmd,
        info_cmd,
        list_cmd,
        map_cmd,
        predict_cmd,
        report_cmd,
        reproduce_cmd,
        speed_cmd,
        synth_cmd,
        train_cmd,
        weights_cmd,
    )

    parser = _Parser(
        prog="evsmap",
        description="Benchmark harness for efficient volumetric-semantic mapping (EVSMaP).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for module in (list_cmd, synth_cmd, info_cmd, reproduce_cmd, complexity_cmd, speed_cmd,
                   map_cmd, datasets_cmd, eval_cmd, report_cmd, weights_cmd,
                   predict_cmd, train_cmd, cache_cmd, gate_cmd):
        module.add_parser(sub)
    return parser


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("evsmap")
    except PackageNotFoundError:
        return "unknown"


def _format_warning(message, category, filename, lineno, line=None) -> str:
    """Warnings as one line (``evsmap: warning: ...``), without the source line."""
    return f"evsmap: warning: {message}\n"


def main(argv: Sequence[str] | None = None) -> int:
    import warnings

    warnings.formatwarning = _format_warning
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.run(args) or 0)
    except EvsmapError as exc:
        sys.stderr.write(f"evsmap {args.command}: error: {exc}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("evsmap: interrupted\n")
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
