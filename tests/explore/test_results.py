"""Pareto fronts and the answer over made-up trial rows; the report and Table IV's link."""

from __future__ import annotations

from pathlib import Path

from evsmap.explore.results import answer, pareto_front


def _row(n: int, size: float, miou: float, ratio: float | None = None,
         loss: float | None = None, role: str = "", **params: float) -> dict:
    return {"number": n, "state": "COMPLETE", "role": role, "map_size": size, "scene_miou": miou,
            "rate_ratio": 1.0, "size_ratio": ratio, "miou_loss": loss,
            **{f"param:{k}": v for k, v in params.items()}}


def test_pareto_front_keeps_the_undominated() -> None:
    rows = [_row(0, 10, 0.30), _row(1, 5, 0.20), _row(2, 12, 0.29), _row(3, 5, 0.25),
            _row(4, 20, 0.35), {**_row(5, 1, 0.9), "state": "FAIL"}]
    from evsmap.explore.results import complete

    front = pareto_front(complete(rows), "map_size", "scene_miou", x_lower=True, y_lower=False)
    assert [r["number"] for r in front] == [3, 0, 4]


def test_answer_needs_a_smaller_map_within_one_point() -> None:
    rows = [_row(0, 10, 0.30, ratio=0.8, loss=4.0, role="paper default", psi=1.0),
            _row(1, 5, 0.29, ratio=1.6, loss=0.5, psi=0.5),
            _row(2, 4, 0.20, ratio=3.0, loss=10.0, psi=0.3),
            _row(3, 6, 0.31, ratio=1.2, loss=-0.2, psi=0.7)]
    found = answer(rows)
    assert [r["number"] for r in found.within] == [1, 3]
    assert found.best["number"] == 1 and found.best_any["number"] == 2
    assert found.default["number"] == 0
    assert found.region == {"psi": (0.5, 0.7)}
    assert not found.reaches_paper
    assert answer([*rows, _row(4, 2, 0.3, ratio=2.7, loss=1.0)]).reaches_paper


def test_report_files_and_table_iv_link(tmp_path: Path, small_space) -> None:
    from evsmap.report.explore import study_markdown, write_report

    rows = [_row(0, 10e6, 0.30, ratio=0.8, loss=4.0, role="paper default", resolution=0.1,
                 raycast_range=2.0, psi=1.0, theta=0.6),
            _row(1, 5e6, 0.29, ratio=1.6, loss=0.5, resolution=0.2, raycast_range=1.0,
                 psi=0.5, theta=0.1)]
    for r in rows:
        r.update(baseline_map_size=8e6, baseline_scene_miou=0.3, baseline_rate_ratio=0.9)
    index, line = write_report(tmp_path / "study", rows, small_space, header={"x": "y"})
    text = index.read_text()
    assert line in text and "1.60x" in line and "not reached" in line
    for name in ("trials.csv", "front-size-miou.png", "front-rate-miou.png"):
        assert (tmp_path / "study" / name).stat().st_size > 0
    assert (tmp_path / "study" / "trials.csv").read_text().count("\n") == 3
    linked = "\n".join(study_markdown({"index": str(index), "summary": line, "written": 0},
                                      tmp_path / "run"))
    assert "(../study/index.md)" in linked and line in linked
    assert study_markdown(None, tmp_path) == []
