"""README.md's "What reproduces here" is what benchmarks/headline.py makes from the shipped runs
its marker names, with today's code: it cannot drift from the data."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmarks import headline
from evsmap.report.headline import END, replace_section, section_runs

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"


def _section(text: str) -> str:
    start = text.index("<!-- headline: ")
    return text[start:text.index(END, start) + len(END)] + "\n"


def test_the_readme_headline_equals_the_command_output():
    text = README.read_text()
    runs = section_runs(text)
    assert runs, "README.md has no '<!-- headline: RUN -->' section"
    assert all((ROOT / r / "run.json").is_file() for r in runs)
    assert _section(text) == headline.section(runs)


def test_the_headline_states_each_claim_with_the_paper_ours_verdict_and_machine():
    runs = section_runs(README.read_text())
    section = headline.section(runs)
    rows = [ln for ln in section.splitlines() if ln.startswith("| ") and "---" not in ln]
    assert rows[0] == "| claim | paper | ours | verdict | machine |"
    body = rows[1:]
    assert any("FEAGNet-V2 runs faster than ESANet-R34" in r for r in body)
    assert all(r.count(" | ") == 4 for r in body)
    assert all(any(v in r for v in ("holds", "does not hold", "cannot be checked here"))
               for r in body)
    assert all(r.rstrip(" |").endswith("2 cores") for r in body)


def test_replace_section_swaps_only_the_section():
    text = "intro\n<!-- headline: results/a -->\nold\n<!-- headline end -->\noutro\n"
    new = replace_section(text, "<!-- headline: results/b -->\nnew\n<!-- headline end -->\n")
    assert new == "intro\n<!-- headline: results/b -->\nnew\n<!-- headline end -->\noutro\n"
    assert section_runs(new) == ["results/b"]
    with pytest.raises(ValueError, match="no section"):
        replace_section("no markers here", "x")


def test_the_command_writes_the_section(tmp_path, capsys):
    runs = section_runs(README.read_text())
    target = tmp_path / "README.md"
    target.write_text("# x\n\n<!-- headline: old -->\n<!-- headline end -->\n\nrest\n")
    assert headline.main([*runs, "--write", str(target)]) == 0
    assert target.read_text() == "# x\n\n" + headline.section(runs) + "\nrest\n"
    assert headline.main(["results/no-such-run"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "results/no-such-run" in err
