"""The import contracts of ``pyproject.toml`` (``[tool.importlinter]``, run by ``nox -s lint``):
evsmap's layers point downward, evsmap never imports ``baselines``, the baselines stay out of the
harness, and no sibling modules import each other in a cycle.

The tree must keep them, and they must catch what they exist for: an upward import and a cycle
planted in a copy of the sources each break a contract, named in the output."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("importlinter", reason="import-linter is in the test extra (nox -s tests)")

ROOT = Path(__file__).resolve().parents[1]


def _lint_imports(cwd: Path) -> subprocess.CompletedProcess[str]:
    script = Path(sys.executable).with_name("lint-imports")
    cmd = [str(script)] if script.exists() else [sys.executable, "-m", "importlinter.cli"]
    return subprocess.run([*cmd, "--config", "pyproject.toml", "--no-cache"], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture
def source_copy(tmp_path: Path) -> Path:
    """The two packages' Python files and pyproject.toml, copied (nothing else is read)."""
    for package in ("evsmap", "baselines"):
        shutil.copytree(ROOT / package, tmp_path / package,
                        ignore=lambda d, names: [n for n in names if n == "__pycache__"
                                                 or (Path(d, n).is_file() and
                                                     not n.endswith(".py"))])
    shutil.copy2(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    return tmp_path


def _append(path: Path, text: str) -> None:
    path.write_text(path.read_text() + "\n" + text + "\n")


def test_the_tree_keeps_every_contract():
    result = _lint_imports(ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


@pytest.mark.parametrize(("module", "planted", "contract", "named"), [
    # an upward import hidden inside a function
    ("evsmap/mapping/keys.py", "def _planted():\n    from evsmap.runner import plan  # noqa",
     "evsmap's layers point downward", "evsmap.mapping.keys"),
    ("evsmap/registry.py", "import baselines  # noqa",
     "evsmap never imports the comparison systems (they register through the evsmap.plugins "
     "entry point)", "evsmap.registry -> baselines"),
    # two modules of one layer that import each other: the layers allow it, the cycle rule not
    ("evsmap/mapping/keys.py", "from evsmap.mapping import tree  # noqa",
     "no import cycles between sibling modules, at any depth", ".tree -> .keys"),
], ids=["upward-import", "imports-baselines", "cycle"])
def test_a_planted_violation_breaks_its_contract(source_copy, module, planted, contract, named):
    _append(source_copy / module, planted)
    result = _lint_imports(source_copy)
    assert result.returncode != 0
    broken = " ".join(result.stdout.split())  # the report wraps long contract names
    assert f"{contract} BROKEN" in broken
    assert named in result.stdout
