"""The fuzzing harness shared by every target under ``tests/fuzz/`` (docs/robustness.md).

The property every target checks, on a file a user could hand evsmap:

* the call returns normally, or raises :class:`~evsmap.errors.EvsmapError` whose message is one
  line and names the file (its name, or a name the caller says the message must carry);
* nothing else escapes: any other exception is a bug (:func:`check_file` fails the example with
  the traceback);
* no hang: an example that runs past :data:`HANG_S` seconds fails (``SIGALRM``; a guard against
  endless loops, not a timing);
* bounded memory: the address space may not grow by more than :data:`MEMORY_BOUND` bytes during
  the call (``RLIMIT_AS`` lowered for its length, Linux), so a header claiming a 10^9-point cloud
  or a 10^5 x 10^5 image fails instead of allocating it.

Budgets come from hypothesis profiles: ``evsmap-ci`` (the test suite: a few dozen derandomised
examples a target, so CI is repeatable) and ``evsmap-fuzz`` (``nox -s fuzz``: random, with the
example database, ``EVSMAP_FUZZ_EXAMPLES`` a target). ``EVSMAP_FUZZ_PROFILE`` picks one.

:data:`CASES` counts the examples run per target; ``tests/fuzz/conftest.py`` prints the counts at
the end of the session and writes them to ``EVSMAP_FUZZ_REPORT`` (JSON) when set.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import traceback
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

from evsmap.errors import EvsmapError

HANG_S = 60.0
"""An example running longer than this is a hang (the slowest legitimate one takes < 5 s)."""

MEMORY_BOUND = 2 * 1024**3
"""How much a single example may grow the address space (bytes): far above any real sample's
decoded size (a 640x480 RGB-D frame with 40-class logits is ~50 MB), far below what a lying
header would claim."""

CASES: Counter[str] = Counter()
"""Examples run per target in this session."""

FAILURES: Counter[str] = Counter()
"""Examples that broke the property, per target (a failing test shrinks, so several count)."""

_SUPPRESS = [HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much,
             HealthCheck.function_scoped_fixture, HealthCheck.large_base_example]


def _examples(default: int) -> int:
    raw = os.environ.get("EVSMAP_FUZZ_EXAMPLES")
    return int(raw) if raw else default


settings.register_profile("evsmap-ci", max_examples=_examples(25), derandomize=True,
                          deadline=None, database=None, suppress_health_check=_SUPPRESS,
                          print_blob=True)
settings.register_profile("evsmap-fuzz", max_examples=_examples(200), deadline=None,
                          suppress_health_check=_SUPPRESS, print_blob=True)


def load_profile() -> str:
    name = "evsmap-" + os.environ.get("EVSMAP_FUZZ_PROFILE", "ci")
    settings.load_profile(name)
    return name


# ------------------------------------------------------------------------------ the property
class Hang(Exception):
    """An example ran past :data:`HANG_S`."""


@contextlib.contextmanager
def _hang_guard(seconds: float) -> Iterator[None]:
    if not hasattr(signal, "setitimer") or \
            signal.getsignal(signal.SIGALRM) not in (signal.SIG_DFL, None):
        yield
        return

    def fire(signum, frame):  # pragma: no cover - only on a hang
        raise Hang(f"still running after {seconds:.0f} s")

    previous = signal.signal(signal.SIGALRM, fire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def _address_space() -> int | None:
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


@contextlib.contextmanager
def memory_bound(extra: int = MEMORY_BOUND) -> Iterator[None]:
    """Lower ``RLIMIT_AS`` to the current address space plus ``extra`` for the block (Linux; a
    no-op elsewhere): an allocation beyond it fails with MemoryError (or the C++ equivalent)."""
    try:
        import resource
    except ImportError:  # pragma: no cover
        yield
        return
    now = _address_space()
    if now is None:
        yield
        return
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    limit = now + extra
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def check_file(target: str, call: Callable[[], Any], path: str | os.PathLike[str] | None,
               *, names: tuple[str, ...] = ()) -> Any:
    """Run ``call()`` (which reads ``path``) under the property; return its result, or None
    when it raised a well-formed :class:`EvsmapError`.

    The message must name the file: ``path``'s name, or one of ``names`` (a member of the
    file, e.g. a bag's topic, or the folder holding it) when given. ``path`` None: the message is
    only checked for being one line.
    """
    CASES[target] += 1
    try:
        with _hang_guard(HANG_S), memory_bound():
            return call()
    except EvsmapError as exc:
        text = str(exc)
        wanted = tuple(names) + ((Path(path).name,) if path is not None else ())
        problems = []
        if "\n" in text.strip():
            problems.append("the message is not one line")
        if wanted and not any(w and w in text for w in wanted):
            problems.append(f"the message names none of {wanted}")
        if not text.strip():
            problems.append("the message is empty")
        if problems:
            FAILURES[target] += 1
            raise AssertionError(f"{target}: {'; '.join(problems)}: {text!r}") from exc
        return None
    except MemoryError as exc:
        FAILURES[target] += 1
        raise AssertionError(f"{target}: allocated beyond the bound of "
                             f"{MEMORY_BOUND / 1024**3:.0f} GiB reading {path}") from exc
    except Hang as exc:
        FAILURES[target] += 1
        raise AssertionError(f"{target}: hang reading {path}: {exc}") from exc
    except Exception as exc:
        FAILURES[target] += 1
        raise AssertionError(f"{target}: {type(exc).__name__} escaped reading {path} (a "
                             f"traceback, not a one-line error):\n"
                             f"{''.join(traceback.format_exception(exc))}") from exc


def check_cli(target: str, argv: list[str], names: tuple[str, ...],
              capsys: Any) -> int:
    """``evsmap ARGV`` in this process under the property: exit 0, or exit 2 with one line on
    stderr naming one of ``names`` and no traceback. Returns the exit status."""
    from evsmap.cli.main import main

    CASES[target] += 1
    capsys.readouterr()
    try:
        with _hang_guard(HANG_S), memory_bound():
            code = main(argv)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 2
    except BaseException as exc:
        FAILURES[target] += 1
        raise AssertionError(f"{target}: evsmap {' '.join(argv)} raised "
                             f"{type(exc).__name__}:\n"
                             f"{''.join(traceback.format_exception(exc))}") from exc
    err = capsys.readouterr().err.strip()
    lines = [line for line in err.splitlines() if not line.startswith("evsmap: warning:")]
    if code == 0:
        return 0
    ok = code == 2 and len(lines) == 1 and "Traceback" not in err and \
        any(n in lines[0] for n in names)
    if not ok:
        FAILURES[target] += 1
        raise AssertionError(f"{target}: evsmap {' '.join(argv)} exited {code} with "
                             f"stderr {err!r} (want 0, or 2 and one line naming one of {names})")
    return code


# ------------------------------------------------------------------------- mutation strategies
MUTATIONS = ("truncate", "flip", "overwrite", "insert", "delete", "duplicate", "zero",
             "ff", "extend", "swap")


@st.composite
def mutated_bytes(draw: st.DrawFn, data: bytes, *, max_ops: int = 4) -> bytes:
    """``data`` with 1..``max_ops`` random edits: truncation, bit flips, overwritten, inserted,
    deleted or duplicated runs, zeroed or 0xFF runs, trailing garbage, swapped halves. Edits
    favour the first kilobyte, where headers live."""
    out = bytearray(data)
    for _ in range(draw(st.integers(1, max_ops))):
        op = draw(st.sampled_from(MUTATIONS))
        n = len(out)

        def pos(limit: int = n) -> int:
            if limit <= 0:
                return 0
            head = draw(st.booleans())
            return draw(st.integers(0, min(limit, 1024) if head else limit))

        if op == "truncate":
            out = out[:pos(n)]
        elif op == "flip" and n:
            i = pos(n - 1)
            out[i] ^= 1 << draw(st.integers(0, 7))
        elif op == "overwrite" and n:
            i = pos(n - 1)
            chunk = draw(st.binary(min_size=1, max_size=16))
            out[i:i + len(chunk)] = chunk
        elif op == "insert":
            i = pos(n)
            out[i:i] = draw(st.binary(min_size=1, max_size=64))
        elif op == "delete" and n:
            i = pos(n - 1)
            del out[i:i + draw(st.integers(1, 256))]
        elif op == "duplicate" and n:
            i = pos(n - 1)
            out[i:i] = out[i:i + draw(st.integers(1, 256))]
        elif op in ("zero", "ff") and n:
            i = pos(n - 1)
            k = draw(st.integers(1, 64))
            out[i:i + k] = (b"\0" if op == "zero" else b"\xff") * len(out[i:i + k])
        elif op == "extend":
            out += draw(st.binary(min_size=1, max_size=256))
        elif op == "swap" and n > 1:
            i = pos(n - 1)
            out = out[i:] + out[:i]
    return bytes(out)


def text_lines(lines: list[str]) -> st.SearchStrategy[str]:
    """Line-level edits of a text file: lines dropped, duplicated, fields replaced by numbers,
    NaN/Inf, words or nothing, fields added or removed, odd separators and encodings."""
    field = st.one_of(
        st.sampled_from(["nan", "inf", "-inf", "NaN", "1e308", "-1e308", "0", "-0", "1e-320",
                         "", " ", "#", "x", "1,5", "0x10", "9" * 40, "\t", "\ufeff1"]),
        st.floats(allow_nan=True, allow_infinity=True).map(repr),
        st.integers(-2**63, 2**64).map(str),
        st.text(max_size=8))

    @st.composite
    def edit(draw: st.DrawFn) -> str:
        out = list(lines)
        for _ in range(draw(st.integers(1, 4))):
            if not out:
                out.append(draw(st.text(max_size=40)))
                continue
            i = draw(st.integers(0, len(out) - 1))
            op = draw(st.sampled_from(["drop", "dup", "field", "add", "remove", "sep", "raw"]))
            parts = out[i].split()
            if op == "drop":
                del out[i]
            elif op == "dup":
                out.insert(i, out[i])
            elif op == "field" and parts:
                parts[draw(st.integers(0, len(parts) - 1))] = draw(field)
                out[i] = " ".join(parts)
            elif op == "add":
                out[i] = out[i] + " " + draw(field)
            elif op == "remove" and parts:
                del parts[draw(st.integers(0, len(parts) - 1))]
                out[i] = " ".join(parts)
            elif op == "sep":
                out[i] = out[i].replace(" ", draw(st.sampled_from([",", "\t", "  ", ";", ""])))
            elif op == "raw":
                out[i] = draw(st.text(max_size=60))
        return "\n".join(out) + draw(st.sampled_from(["\n", "", "\r\n", "\n\n"]))

    return edit()


def write_variant(path: Path, data: bytes | str) -> Path:
    """Write one example's file (bytes, or text as UTF-8 with unencodable characters escaped)."""
    if isinstance(data, str):
        data = data.encode("utf-8", "surrogateescape") if sys.platform != "win32" \
            else data.encode("utf-8", "replace")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path
