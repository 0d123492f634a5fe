"""`evsmap report RUN --format latex` and the comparison's LaTeX: booktabs tables whose rows
have the tabular's column count, measured beside the paper, precisions, lettered notes for the
cells not measured, the machine in the caption, special characters escaped; compiled where a
LaTeX engine is installed."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest
from conftest import make_run

from benchmarks import ship_run
from evsmap.cli.main import main
from evsmap.report.compare import compare_runs
from evsmap.report.latex import compare_latex, escape

ROOT = Path(__file__).resolve().parents[2]
QUICK = next(f for f in ship_run.shipped(ROOT / "results") if f.name.endswith("_quick"))
_MULTI = re.compile(r"\\multicolumn\{(\d+)\}")


def _columns(spec: str) -> int:
    return len(re.findall(r"[lcr]", spec))


def _cells(row: str) -> int:
    """The columns a tabular row spans (``&`` outside ``\\&``, multicolumns counted whole)."""
    parts = re.split(r"(?<!\\)&", row.removesuffix(r"\\").strip())
    return sum(int(m.group(1)) if (m := _MULTI.search(p)) else 1 for p in parts)


def check_tabulars(text: str) -> int:
    """Every tabular of ``text`` is balanced, booktabs-ruled, and each row spans its column
    count; returns how many there are."""
    assert text.count(r"\begin{table}") == text.count(r"\end{table}")
    assert text.count(r"\begin{tabular}") == text.count(r"\end{tabular}")
    blocks = re.findall(r"\\begin\{tabular\}\{([^}]*)\}\n(.*?)\\end\{tabular\}", text, re.S)
    for spec, body in blocks:
        lines = body.strip().splitlines()
        assert lines[0] == r"\toprule" and lines[-1] == r"\bottomrule"
        assert lines.count(r"\midrule") == 1
        rows = [ln for ln in lines if ln.endswith(r"\\")]
        assert rows and all(_cells(r) == _columns(spec) for r in rows), spec
    return len(blocks)


def test_escape_writes_every_special_character_as_a_command():
    assert escape("WA&HA 50% $5 #1 a_b {x} ~ ^ \\") == (
        r"WA\&HA 50\% \$5 \#1 a\_b \{x\} \textasciitilde{} \textasciicircum{} "
        r"\textbackslash{}")
    assert escape("ESANet-R34Δ 1024×512 7.9†") == (
        r"ESANet-R34\ensuremath{\Delta} 1024\ensuremath{\times}512 7.9\textsuperscript{\dag}")


@pytest.fixture(scope="module")
def quick_tex(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("tex") / QUICK.name
    run.mkdir()
    shutil.copy2(QUICK / "run.json", run / "run.json")
    shutil.copytree(QUICK / "records", run / "records")
    assert main(["report", str(run), "--format", "latex"]) == 0
    return run


def test_report_writes_tables_one_to_four_as_booktabs(quick_tex):
    names = {p.name for p in quick_tex.glob("*.tex")}
    assert names == {"table1.tex", "table2.tex", "table3.tex", "table4.tex", "tables.tex"}
    assert not (quick_tex / "index.md").exists()  # only the LaTeX was asked for
    for tid in ("table1", "table2", "table3", "table4"):
        text = (quick_tex / f"{tid}.tex").read_text()
        assert check_tabulars(text) == 1
        assert "AMD EPYC, avx512-vnni, 2 cores" in text and r"\caption{" in text
        assert "measured & paper" in text
    table1 = (quick_tex / "table1.tex").read_text()
    assert r"FPS" in table1 and re.search(r"\$\d+\.\d+ \\pm \d+\.\d+\$", table1)
    assert r"n/a\textsuperscript{a}" in table1 and r"\textsuperscript{a}~needs" in table1
    assert r"MIoU NYUv2 (\%)" in table1 and r"ESANet-R34\ensuremath{\Delta}" in table1
    assert r"WA\&HA" in (quick_tex / "table3.tex").read_text()
    doc = (quick_tex / "tables.tex").read_text()
    assert r"\usepackage{booktabs}" in doc and r"\input{table4.tex}" in doc


def test_a_hand_made_run_with_errors_and_paper_only_rows(tmp_path):
    run = make_run(tmp_path / "run", artifacts=False)
    assert main(["report", str(run), "--format", "latex"]) == 0
    text = (run / "table1.tex").read_text()
    assert check_tabulars(text) == 1
    assert r"error\textsuperscript{" in text and "RuntimeError: boom" in text
    assert "Test CPU @ 3 GHz" in text


def test_the_comparison_as_latex(tmp_path):
    text = compare_latex(compare_runs([QUICK], paper=True))
    assert check_tabulars(text) >= 3
    assert r"\times$" in text and "paper" in text


ENGINES = [e for e in ("tectonic", "pdflatex") if shutil.which(e)]


@pytest.mark.skipif(not ENGINES, reason="no LaTeX engine (pdflatex, tectonic) installed")
def test_the_tables_compile(quick_tex):
    engine = ENGINES[0]
    argv = [engine, "tables.tex"] if engine == "tectonic" else \
        [engine, "-interaction=nonstopmode", "-halt-on-error", "tables.tex"]
    proc = subprocess.run(argv, cwd=quick_tex, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert (quick_tex / "tables.pdf").stat().st_size > 0
