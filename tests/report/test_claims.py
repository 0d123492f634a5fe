"""The paper's claims checked as ratios, and each table relative to its baseline row."""

from __future__ import annotations

import pandas as pd

from evsmap.report.claims import CLAIMS, Claim, check, claims_markdown, relative_markdown
from evsmap.tables import load_tables


def _frame(cells, precision=None):
    rows = [{"row": r, "column": c, "label": r, "status": s, "measured": m, "paper": p,
             "note": n, "timing_flag": f, "unit": "FPS" if c == "fps" else "%",
             "rel_ci": (precision or {}).get(r)}
            for (r, c), (s, m, p, n, f) in cells.items()]
    return pd.DataFrame(rows)


def test_a_speed_claim_holds_with_its_ratio_beside_the_papers():
    frame = _frame({("feagnet-v2", "fps"): ("ok", 30.0, 28.1, "", None),
                    ("esanet-r34", "fps"): ("ok", 10.0, 10.0, "", None)})
    claim = Claim("faster", "table1", "feagnet-v2", "esanet-r34", "fps", "higher")
    r = check(claim, frame)
    assert r["verdict"] == "holds" and r["measured"] == 3.0 and abs(r["paper"] - 2.81) < 1e-9
    slower = _frame({("feagnet-v2", "fps"): ("ok", 9.0, 28.1, "", "unstable: ..."),
                     ("esanet-r34", "fps"): ("ok", 10.0, 10.0, "", None)})
    r = check(claim, slower)
    assert r["verdict"] == "does not hold" and "flagged" in r["why"]


def test_a_claim_without_its_cells_says_why():
    frame = _frame({("feagnet-v2", "miou_nyuv2"): ("n/a", None, 48.0,
                                                  "n/a - needs the nyuv2 dataset", None),
                    ("esanet-r34", "miou_nyuv2"): ("ok", 50.0, 50.6, "", None)})
    claim = next(c for c in CLAIMS if c.column == "miou_nyuv2")
    r = check(claim, frame)
    assert r["verdict"] == "cannot be checked here" and "needs the nyuv2 dataset" in r["why"]
    assert "esanet" not in r["why"]


def test_a_match_claim_allows_five_percent():
    claim = Claim("share", "table1", "a", "b", "miou_nyuv2", "match")
    near = _frame({("a", "miou_nyuv2"): ("ok", 47.0, 48.0, "", None),
                   ("b", "miou_nyuv2"): ("ok", 50.0, 50.0, "", None)})
    assert check(claim, near)["verdict"] == "holds"  # 0.94 against the paper's 0.96
    far = _frame({("a", "miou_nyuv2"): ("ok", 40.0, 48.0, "", None),
                  ("b", "miou_nyuv2"): ("ok", 50.0, 50.0, "", None)})
    assert check(claim, far)["verdict"] == "does not hold"


def test_index_section_and_relative_view():
    table = load_tables()["table1"]
    frame = _frame({("feagnet-v2", "fps"): ("ok", 30.0, 28.1, "", None),
                    ("esanet-r34", "fps"): ("ok", 10.0, 10.0, "", None)},
                   precision={"feagnet-v2": 0.012, "esanet-r34": 0.02})
    md = "\n".join(claims_markdown({"table1": frame}))
    assert md.startswith("## What reproduces here")
    # a ratio of two timings: their precisions added
    assert ("| FEAGNet-V2 runs faster than ESANet-R34 (Table I, FPS) | 3.00x | +-3.2 % | 2.81x "
            "| holds |") in md
    rel = "\n".join(relative_markdown(table, frame))
    assert "Relative to" in rel and "3.00x / 2.81x" in rel
    assert relative_markdown(load_tables()["table3"], frame) == []


def test_a_timing_claim_is_drift_corrected_with_the_plain_ratio_kept():
    frame = _frame({("feagnet-v2", "fps"): ("ok", 30.0, 28.1, "", None),
                    ("esanet-r34", "fps"): ("ok", 8.0, 10.0, "", None)})
    frame["calibration_gmacs"] = [100.0, 80.0]  # the machine ran 20 % slower for ESANet
    claim = Claim("faster", "table1", "feagnet-v2", "esanet-r34", "fps", "higher")
    r = check(claim, frame)
    assert abs(r["measured"] - 3.0) < 1e-9 and abs(r["raw"] - 3.75) < 1e-9
    md = "\n".join(claims_markdown({"table1": frame}))
    assert "(plain 3.75x)" in md
