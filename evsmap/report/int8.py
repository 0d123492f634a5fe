"""The "int8 beside fp32" section of Tables I-III and ``int8.csv`` (``evsmap reproduce
--precision int8``, records ``extra/int8/...`` from :mod:`evsmap.runner.int8`)."""

from __future__ import annotations

from collections.abc import Iterable

import pandas as pd

from evsmap.runner.records import CellRecord

PREFIX = "extra/int8/"
SECTION = "int8 beside fp32 (ONNX Runtime, static QDQ quantisation)"
COLUMNS = ("key", "table", "row", "segmenter", "input", "status", "fp32_ms", "fp32_ms_iqr",
           "int8_ms", "int8_ms_iqr", "speedup", "agreement", "miou_fp32", "miou_int8",
           "scheme", "scheme_chosen_by", "instruction_set", "fp32_nodes", "note")
"""Columns of ``int8.csv`` (milliseconds; agreement and mIoU as fractions)."""


def int8_records(records: Iterable[CellRecord], table: str | None = None) -> list[CellRecord]:
    """The int8 records (of ``table``'s networks when given), in key order."""
    out = [r for r in records if r.key.startswith(PREFIX)
           and (table is None or r.inputs.get("table") == table)]
    return sorted(out, key=lambda r: r.key)


def _fmt(value, scale: float = 1.0, digits: int = 1) -> str:
    if value is None or value != value:
        return "-"
    return f"{value * scale:.{digits}f}"


def _input(rec: CellRecord) -> str:
    size = rec.inputs.get("input_size")
    return f"{size[1]}x{size[0]}" if size else "-"


def int8_markdown(records: Iterable[CellRecord], table: str) -> list[str]:
    """The section for ``table``'s networks (empty without int8 records)."""
    recs = int8_records(records, table)
    if not recs:
        return []
    out = [f"## {SECTION}", "",
           "Measured in this run, not the paper's: each network's forward pass in fp32 and in "
           "int8 (QDQ in the scheme of the Scheme column, calibrated on 16 synthetic frames; "
           "`auto` picks u8s8 with VNNI, u8s7 on x86 without it), alternating on one input, on "
           "ONNX Runtime with the run's threads; top-1 agreement: pixels whose class int8 keeps, "
           "on held-out synthetic frames (untrained seeded weights unless weights were found: a "
           "floor); mIoU where the run has the dataset and weights (int8 calibrated on the "
           "train split).", "",
           "| Network | Input | fp32 (ms) | int8 (ms) | Speed-up | Top-1 agreement (%) | "
           "mIoU fp32 / int8 (%) | Nodes kept fp32 | Scheme |",
           "|---|---|---:|---:|---:|---:|---:|---:|---|"]
    for rec in recs:
        v = rec.values
        if rec.status != "ok":
            why = rec.error or rec.reason or rec.status
            out.append(f"| {rec.label} | {_input(rec)} | {rec.status}: {why} | | | | | | |")
            continue
        miou = (f"{_fmt(v.get('miou_fp32'), 100)} / {_fmt(v.get('miou_int8'), 100)}"
                if v.get("miou_int8") is not None else "needs weights")
        quant = rec.details.get("quantization") or {}
        q = quant.get("int8") or {}
        out.append(
            f"| {rec.label} | {_input(rec)} | {_fmt(v.get('fp32_ms'))} | "
            f"{_fmt(v.get('int8_ms'))} | x{_fmt(v.get('speedup'), digits=2)} | "
            f"{_fmt(v.get('agreement'), 100)} | {miou} | {q.get('fp32_nodes', '-')} | "
            f"{_scheme_text(quant)} |")
    return out + [""]


def _scheme_text(quant: dict) -> str:
    """``u8s7 (auto for avx2)``; older records name the scheme alone."""
    scheme = quant.get("int8_scheme") or "-"
    chosen_by = quant.get("int8_scheme_chosen_by")
    return f"{scheme} ({chosen_by})" if chosen_by else scheme


def int8_frame(records: Iterable[CellRecord]) -> pd.DataFrame:
    """``int8.csv``: one line per int8 record."""
    lines = []
    for rec in int8_records(records):
        v = rec.values if rec.status == "ok" else {}
        q = (rec.details.get("quantization") or {})
        lines.append({
            "key": rec.key, "table": rec.inputs.get("table"), "row": rec.row,
            "segmenter": rec.inputs.get("segmenter"), "input": _input(rec),
            "status": {"na": "n/a"}.get(rec.status, rec.status),
            **{k: v.get(k) for k in ("fp32_ms", "fp32_ms_iqr", "int8_ms", "int8_ms_iqr",
                                     "speedup", "agreement", "miou_fp32", "miou_int8")},
            "scheme": q.get("int8_scheme"), "scheme_chosen_by": q.get("int8_scheme_chosen_by"),
            "instruction_set": q.get("instruction_set"),
            "fp32_nodes": (q.get("int8") or {}).get("fp32_nodes"),
            "note": "; ".join(rec.notes) if rec.status == "ok" else (rec.error or rec.reason)})
    return pd.DataFrame(lines, columns=list(COLUMNS))
