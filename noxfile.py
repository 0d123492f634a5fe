"""Developer and CI sessions. Every install goes through constraints.txt, the full lock of the
runtime and test dependencies (torch==2.13.0 CPU among them); `nox -s lock` regenerates it."""

from __future__ import annotations

import os
import re
from pathlib import Path

import nox

nox.options.sessions = ["tests", "lint"]
nox.options.reuse_existing_virtualenvs = True
LOCK = "constraints.txt"
CONSTRAINTS = ("-c", LOCK)


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
def fuzz(session: nox.Session) -> None:
    """Every fuzz target under tests/fuzz with the long budget (docs/robustness.md): random
    examples, EVSMAP_FUZZ_EXAMPLES per target (default 200), hypothesis's example database in
    .hypothesis/ (a failure found once is tried first next time). The examples run per target
    are printed and written to reports/fuzz.json. `nox -s fuzz -- -k rosbag` runs a subset; the
    test suite runs every target with 25 derandomised examples."""
    _install(session)
    env = {"EVSMAP_FUZZ_PROFILE": "fuzz",
           "EVSMAP_FUZZ_EXAMPLES": os.environ.get("EVSMAP_FUZZ_EXAMPLES", "200"),
           "EVSMAP_FUZZ_REPORT": os.environ.get("EVSMAP_FUZZ_REPORT", "reports/fuzz.json")}
    session.run("pytest", "tests/fuzz", "-q", "-p", "no:cacheprovider", *session.posargs,
                env=env)


@nox.session
def lint(session: nox.Session) -> None:
    """ruff over the code, the import contracts of pyproject.toml (import-linter: the layers
    point downward, no cycles, evsmap never imports the baselines), then mypy over evsmap
    (``[tool.mypy]``: strict on the contracts, measuring, running and mapping code). mypy reads
    the dependencies' types, so the project is installed from the lock as for the tests."""
    _install(session)
    session.install(*CONSTRAINTS, "ruff", "import-linter", "mypy")
    session.run("ruff", "check", "evsmap", "baselines", "benchmarks", "tests", "noxfile.py")
    session.run("lint-imports", "--config", "pyproject.toml", "--no-cache")
    session.run("mypy", "--config-file", "pyproject.toml", *session.posargs)


@nox.session
def gates(session: nox.Session) -> None:
    """Regression gates on speed and memory against benchmarks/baseline.json (`evsmap gate`;
    `nox -s gates -- --update` records a new baseline, `-- --only 'net/*'` a subset)."""
    _install(session)
    session.run("evsmap", "gate", *session.posargs)


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


@nox.session
def explore(session: nox.Session) -> None:
    """`evsmap explore`: the design-space study of EVSMaP's map (docs/explore.md); extra
    arguments are passed on (default: `--out reports/explore`, 40 trials on the synthetic room)."""
    _install(session, extras="test")
    args = list(session.posargs) or ["--out", "reports/explore"]
    session.run("evsmap", "explore", *args)


@nox.session
def fetch(session: nox.Session) -> None:
    """`evsmap datasets fetch`: real sample data (`nox -s fetch -- tum-fr1-xyz`; alone: a list)."""
    _install(session)
    session.run("evsmap", "datasets", "fetch", *session.posargs)


@nox.session
def lock(session: nox.Session) -> None:
    """Regenerate constraints.txt: every dependency of every extra resolved afresh (pip-tools).

    Inputs: pyproject.toml and requirements/pins.in (torch==2.13.0). Extra arguments go to
    pip-compile, e.g. `nox -s lock -- --upgrade-package numpy` instead of the full upgrade.
    """
    session.install(*CONSTRAINTS, "pip-tools")
    args = list(session.posargs) or ["--upgrade"]
    session.run("pip-compile", "--quiet", "--all-extras", "--strip-extras", "--no-emit-index-url",
                "--no-emit-find-links", "--output-file", LOCK, *args, "pyproject.toml",
                "requirements/pins.in", env={"CUSTOM_COMPILE_COMMAND": "nox -s lock"})
    _portable_torch_pin(Path(LOCK))


def _portable_torch_pin(path: Path) -> None:
    """`torch==2.13.0+cpu` (a local wheel's version) -> `torch==2.13.0`, which both the CPU wheel
    and PyPI's build satisfy, so the lock installs on machines with either index."""
    text = path.read_text()
    path.write_text(re.sub(r"^(torch==[0-9.]+)\+\w+", r"\1", text, flags=re.MULTILINE))
