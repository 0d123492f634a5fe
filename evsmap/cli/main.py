"""The ``evsmap`` command line.

User errors (:class:`evsmap.errors.EvsmapError`, bad options) print one line on stderr and exit
with status 2, and so does a file that cannot be written (a full disk, a read-only folder: the
line names the path). Ctrl-C (SIGINT) and SIGTERM stop the command (:mod:`evsmap.interrupt`),
print how to resume it where it says, and exit with 130 or 143. Anything else is a bug and keeps
its traceback.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

from evsmap.errors import EvsmapError


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump) and exit status 2."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"{self.prog}: error: {message} (see --help)\n")
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    from evsmap.cli import (
        cache_cmd,
        compare_cmd,
        complexity_cmd,
        datasets_cmd,
        eval_cmd,
        explore_cmd,
        gate_cmd,
        info_cmd,
        list_cmd,
        map_cmd,
        oracle_cmd,
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
                   map_cmd, datasets_cmd, eval_cmd, report_cmd, compare_cmd, weights_cmd,
                   predict_cmd, train_cmd, cache_cmd, gate_cmd, explore_cmd, oracle_cmd):
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


def _leave_now(status: int) -> None:
    """End an interrupted command at once: run the exit handlers (multiprocessing's among them:
    its semaphores are released, its workers are already gone), flush the output, and skip the
    interpreter's teardown of its modules, which takes a second or more once torch is loaded
    (every file evsmap wrote is closed and in place by now)."""
    import atexit
    import os

    try:
        atexit._run_exitfuncs()
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(status)


def main(argv: Sequence[str] | None = None) -> int:
    import warnings

    warnings.formatwarning = _format_warning
    from evsmap.interrupt import handle_signals, interruption_behind

    with handle_signals():  # before the parser: building it imports for half a second
        try:
            parser = build_parser()
            args = parser.parse_args(argv)
        except KeyboardInterrupt as exc:
            return _interrupted(exc, "evsmap", leave=argv is None)
        try:
            return int(args.run(args) or 0)
        except EvsmapError as exc:
            interrupt = interruption_behind(exc)
            if interrupt is not None:  # e.g. an import broken off by Ctrl-C, seen as missing
                return _interrupted(interrupt, f"evsmap {args.command}", leave=argv is None)
            sys.stderr.write(f"evsmap {args.command}: error: {exc}\n")
            return 2
        except KeyboardInterrupt as exc:
            return _interrupted(exc, f"evsmap {args.command}", leave=argv is None)
        except BrokenPipeError:
            return 0
        except OSError as exc:
            message = write_failure(exc)
            if message is None:
                raise
            sys.stderr.write(f"evsmap {args.command}: error: {message}\n")
            return 2
        except Exception as exc:
            # e.g. a signal seen through compiled code (numba, torch) as a SystemError
            interrupt = interruption_behind(exc)
            if interrupt is None:
                raise
            return _interrupted(interrupt, f"evsmap {args.command}", leave=argv is None)


def _interrupted(exc: KeyboardInterrupt, prog: str, *, leave: bool) -> int:
    """The line of an interrupted command (with its resume hint) and its exit status; the
    console script (``leave``) ends right here (:func:`_leave_now`)."""
    from evsmap.interrupt import Interrupted, resume_hint

    signum = exc.signum if isinstance(exc, Interrupted) else 2
    hint = resume_hint()
    name = "SIGTERM" if signum == 15 else "Ctrl-C" if signum == 2 else f"signal {signum}"
    sys.stderr.write(f"{prog}: interrupted ({name})" + (f"; {hint}" if hint else "") + "\n")
    if leave:
        _leave_now(128 + signum)
    return 128 + signum


def write_failure(exc: OSError) -> str | None:
    """One line for an OS error a user can fix (:data:`evsmap.fileio.WRITE_ERRNOS`: full disk,
    no permission, read-only folder), naming the path; None for any other."""
    from evsmap.fileio import WRITE_ERRNOS

    if exc.errno not in WRITE_ERRNOS:
        return None
    path = exc.filename
    reason = exc.strerror or str(exc)
    if path is None:
        return f"{reason} ({exc})" if str(exc) != reason else reason
    hidden = Path(str(path))
    # a temporary file (.NAME.PID.HEX.tmp, evsmap.fileio) is named by the file it would become
    if hidden.name.startswith(".") and hidden.name.endswith(".tmp"):
        parts = hidden.name[1:].rsplit(".", 3)
        if len(parts) == 4:
            hidden = hidden.with_name(parts[0])
    return f"{hidden}: {reason}"


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
