"""The semantic-detail section (evsmap/runner/detail.py, evsmap/report/detail.py): its runs on
the synthetic room and on the ScanNet scenes under the data root (an n/a run naming the dataset
without them), one network for every update, the 3D scores in the records, the section and the
claim line."""

from __future__ import annotations

import numpy as np

from evsmap.report.detail import detail_markdown, difference, verdict_rows
from evsmap.runner.context import RunContext
from evsmap.runner.detail import DETAIL_ROWS, detail_row
from evsmap.runner.mapping_record import mapping_record
from evsmap.runner.matrix import plan
from evsmap.segmenters.oracle_profile import DEFAULT_PROFILE
from tests.readers import scannet_scene as scene


def _detail(runs):
    """The section's own rows (not the synthetic room's label-source runs)."""
    return [r for r in runs if r.row.startswith("detail-") and r.labels is None]


def test_without_scannet_the_section_names_the_dataset(tmp_path):
    ctx = RunContext.create(tmp_path / "run", data_root=tmp_path, quick=True)
    runs = _detail(plan(ctx, ["table4"]).runs)
    assert {r.sequence for r in runs} == {"synthetic", "scannet"}
    assert len(runs) == 2 * len(DETAIL_ROWS)
    semantic = [r for r in runs if r.segmenter is not None]
    assert len({r.segmenter.spec for r in semantic}) == 1  # one network feeds every update
    missing = next(r for r in runs if r.sequence == "scannet")
    record = mapping_record(missing, ctx)
    assert record.status == "na" and record.needs == ["dataset:scannet"]
    lines = verdict_rows([record])
    assert len(lines) == 1 and "cannot be checked here" in lines[0]


def test_scannet_scene_is_mapped_and_scored(tmp_path):
    scene.write_scene(tmp_path / "scannet", "scene0000_00")
    ctx = RunContext.create(tmp_path / "run", data_root=tmp_path, quick=True)
    ctx.scannet_step = 1
    runs = [r for r in _detail(plan(ctx, ["table4"]).runs)
            if r.sequence == "scannet-scene0000_00"]
    assert [r.row for r in runs] == [detail_row(r) for r in DETAIL_ROWS]
    records = [mapping_record(r, ctx) for r in runs]
    assert all(r.status == "ok" for r in records), [r.reason for r in records]
    # the lost frame (-inf pose) is left out, not a failure
    assert all(r.values["frames"] == scene.FRAMES - 1 for r in records)
    evsmap, tesamap = records[2], records[1]
    for r in (evsmap, tesamap):
        assert 0 < r.values["scene_miou"] <= 1 and r.details["quality"]["ground_truth"] > 0
    diff = difference({r.row: r for r in records})
    assert np.isclose(diff, evsmap.values["scene_miou"] - tesamap.values["scene_miou"])
    assert records[0].details.get("labels_from") is None  # ORGBMap reads no labels
    # no weights here: the oracle, with its profile named
    assert all(r.details["labels_from"] == f"oracle (profile {DEFAULT_PROFILE})"
               for r in records[1:])
    text = "\n".join(detail_markdown(records))
    assert text.count(f"| oracle, profile {DEFAULT_PROFILE} |") == 2
    assert "### scannet-scene0000_00 at 2 cm" in text and "ORGBMap" in text
    claim = verdict_rows(records)
    assert len(claim) == 1 and "scannet-scene0000_00" in claim[0]
    assert ("holds" if diff >= -0.01 else "does not hold") in claim[0]
