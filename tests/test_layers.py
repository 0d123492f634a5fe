"""The package's layers point downward: the command line sits on top and nothing below imports
it; the map core does not reach up into the runner; the networks do not reach up into the
runner or the command line.

Every ``import`` / ``from ... import`` in every module under ``evsmap/`` and ``baselines/`` is
read from the source (the AST, so imports inside functions count too; nothing is imported)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("evsmap", "baselines")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path) -> list[tuple[int, str]]:
    """``(line, imported module)`` for each import in ``path``; ``from A import b`` counts as
    ``A`` and ``A.b`` (``b`` may be a submodule); relative imports are resolved."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = _module_name(path).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            found.append((node.lineno, module))
            found += [(node.lineno, f"{module}.{alias.name}") for alias in node.names
                      if alias.name != "*"]
    return found


def _all_imports() -> dict[str, list[tuple[str, int, str]]]:
    """Module name -> ``(file, line, imported module)`` of every module of the packages."""
    out: dict[str, list[tuple[str, int, str]]] = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            out[_module_name(path)] = [(rel, line, m) for line, m in _imports(path)]
    return out


IMPORTS = _all_imports()


def _within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def _violations(importers: str, forbidden: tuple[str, ...], *,
                allowed: frozenset[tuple[str, str]] = frozenset()) -> list[str]:
    """``file:line imports module`` for each import of a ``forbidden`` package by a module of
    ``importers`` (itself excluded), except the ``(file, module)`` pairs in ``allowed``."""
    bad = []
    for name, imports in IMPORTS.items():
        if not _within(name, importers):
            continue
        for rel, line, module in imports:
            if any(_within(module, f) and not _within(name, f) for f in forbidden) and \
                    (rel, module) not in allowed:
                bad.append(f"{rel}:{line} imports {module}")
    return sorted(set(bad))


def test_the_scan_sees_the_package():
    assert "evsmap.cli.main" in IMPORTS and "evsmap.runner.context" in IMPORTS
    assert "baselines" in IMPORTS
    # imports inside functions are seen (the runner reads datasets lazily)
    assert any(m == "evsmap.datasets.lookup" for _, _, m in IMPORTS["evsmap.runner.execute"])


def test_nothing_below_the_command_line_imports_it():
    bad = []
    for name, imports in IMPORTS.items():
        if _within(name, "evsmap.cli") or name == "evsmap.__main__":
            continue
        bad += [f"{rel}:{line} imports {module}" for rel, line, module in imports
                if _within(module, "evsmap.cli")]
    assert not bad, ("evsmap.cli is the top layer: move what these modules need out of it "
                     "(e.g. evsmap.datasets.lookup, evsmap.readers.detect, "
                     "evsmap.segmenters.cards, evsmap.options):\n" + "\n".join(sorted(bad)))


@pytest.mark.parametrize(("importers", "forbidden"), [
    ("evsmap.mapping", ("evsmap.runner", "evsmap.cli", "evsmap.train", "evsmap.report")),
    ("evsmap.models", ("evsmap.runner", "evsmap.cli", "evsmap.train", "evsmap.report")),
])
def test_core_packages_do_not_import_the_layers_above(importers, forbidden):
    bad = _violations(importers, forbidden)
    assert not bad, f"{importers} imports a layer above it:\n" + "\n".join(bad)


KNOWN_MAPPING_TO_UPDATERS = frozenset({
    # PLY export checks that it was given an octree updater (imported inside the function)
    ("evsmap/mapping/export.py", "evsmap.updaters.base"),
    ("evsmap/mapping/export.py", "evsmap.updaters.base.OctreeUpdater"),
})


def test_mapping_does_not_import_the_updaters_beyond_the_known_exception():
    bad = _violations("evsmap.mapping", ("evsmap.updaters",), allowed=KNOWN_MAPPING_TO_UPDATERS)
    assert not bad, ("evsmap.mapping is the map core below the updaters (they build on it):\n"
                     + "\n".join(bad))
