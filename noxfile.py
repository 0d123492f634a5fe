"""Developer and CI sessions. Every install goes through constraints.txt (torch==2.13.0 CPU)."""

from __future__ import annotations

import nox

nox.options.sessions = ["tests", "lint"]
nox.options.reuse_existing_virtualenvs = True
CONSTRAINTS = ("-c", "constraints.txt")


def _install(session: nox.Session, extras: str = "test") -> None:
    # torch first and alone, pinned, so no resolver step can pick a newer (CUDA) build
    session.install(*CONSTRAINTS, "torch==2.13.0")
    session.install(*CONSTRAINTS, "-e", f".[{extras}]")


@nox.session
def tests(session: nox.Session) -> None:
    """The test suite (benchmarks excluded)."""
    _install(session)
    session.run("pytest", "tests", *session.posargs)


@nox.session
def lint(session: nox.Session) -> None:
    """ruff over the code."""
    session.install(*CONSTRAINTS, "ruff")
    session.run("ruff", "check", "evsmap", "baselines", "benchmarks", "tests", "noxfile.py")


@nox.session
def bench(session: nox.Session) -> None:
    """pytest-benchmark suites under benchmarks/ (results saved under .benchmarks/)."""
    _install(session)
    session.run("pytest", "benchmarks", "--benchmark-only", "--benchmark-autosave",
                "--benchmark-columns=min,median,iqr,max,rounds", *session.posargs)


@nox.session
def reproduce(session: nox.Session) -> None:
    """The main job: `evsmap reproduce` (extra arguments are passed on)."""
    _install(session, extras="test")
    session.run("evsmap", "reproduce", *session.posargs)
