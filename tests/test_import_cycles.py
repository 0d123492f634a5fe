"""No import cycle among evsmap's modules, counting every import: at module level, inside
functions and under ``if TYPE_CHECKING:``.

import-linter's ``acyclic_siblings`` contract (``nox -s lint``, tests/test_architecture.py) looks
at siblings and skips type-checking imports; this test builds the whole module graph with grimp
(import-linter's graph library) and fails listing each cycle with the imports that close it."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from pathlib import Path

import pytest

grimp = pytest.importorskip("grimp", reason="grimp comes with import-linter (the test extra)")

ROOT = Path(__file__).resolve().parents[1]

def strongly_connected(graph: Mapping[str, Iterable[str]]) -> list[list[str]]:
    """The strongly connected components of ``graph`` (node -> nodes it imports) with more than
    one node, each sorted, in sorted order (Tarjan's algorithm, without recursion)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for start in sorted(graph):
        if start in index:
            continue
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        work = [(start, iter(sorted(graph[start])))]
        while work:
            node, edges = work[-1]
            for nxt in edges:
                if nxt not in graph:
                    continue
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph[nxt]))))
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return sorted(found)


def _evsmap_graph():
    import evsmap

    assert Path(evsmap.__file__).resolve().parent == ROOT / "evsmap", \
        f"evsmap is imported from {evsmap.__file__}, not from this tree"
    return grimp.build_graph("evsmap", include_external_packages=False,
                             exclude_type_checking_imports=False, cache_dir=None)


def _describe(graph, cycle: list[str]) -> str:
    members = set(cycle)
    lines = [" <-> ".join(cycle)]
    for importer in cycle:
        for imported in sorted(graph.find_modules_directly_imported_by(importer) & members):
            for detail in graph.get_import_details(importer=importer, imported=imported):
                lines.append(f"    {importer} -> {imported} (line {detail['line_number']}: "
                             f"{detail['line_contents']})")
    return "\n".join(lines)


def test_finder_sees_cycles_of_any_length():
    graph = {"a": ["b"], "b": ["c"], "c": ["a", "d"], "d": [], "e": ["f"], "f": ["e"],
             "g": ["g"], "h": ["outside"]}
    assert strongly_connected(graph) == [["a", "b", "c"], ["e", "f"]]
    assert strongly_connected({"a": ["b"], "b": ["c"], "c": []}) == []


def test_no_import_cycles():
    graph = _evsmap_graph()
    imports = {m: graph.find_modules_directly_imported_by(m) for m in graph.modules}
    cycles = strongly_connected(imports)
    assert not cycles, "import cycles (imports in functions and under TYPE_CHECKING count):\n" \
        + "\n".join(_describe(graph, c) for c in cycles)
