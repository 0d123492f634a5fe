"""A hand-made run folder: run.json, records of every kind (ok, n/a, error, missing,
multi-column, extra) and small artifacts."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from evsmap.runner.records import CellRecord, RecordStore, needs_text
from evsmap.tables import expand_all

RUN = {
    "run": "20250101-120000", "started": "2025-01-01T12:00:00+00:00",
    "finished": "2025-01-01T12:30:00+00:00",
    "tables": ["table1", "table2", "table3", "table4"], "quick": True,
    "environment": {"cpu": "Test CPU @ 3 GHz", "instruction_set": "avx2",
                    "cpu_flags": ["sse4_2", "avx", "avx2", "fma"], "cpus": 2, "threads": 2,
                    "python": "3.11.9",
                    "versions": {"torch": "2.13.0", "onnxruntime": "1.20.0", "numpy": "2.1.0",
                                 "numba": "0.60.0", "octomap-python": None},
                    "git_commit": "abc1234", "host": "testhost"},
    "data_root": "/data", "weights_dir": None, "available": ["dataset:tum"],
    "sequences": {"synthetic": {"frames": 8, "width": 320, "height": 240,
                                "scene": "living_room", "labels": "ground truth"}},
    "cells": [],
}


def spec_key(table: str, row: str, prefix: str) -> str:
    """The key of the cell of ``table``/``row`` whose key starts with ``table/row/prefix``."""
    keys = [s.key for s in expand_all() if s.table == table and s.row == row
            and s.key.startswith(f"{table}/{row}/{prefix}")]
    assert len(keys) == 1, keys
    return keys[0]


def rec(table: str, row: str, prefix: str, label: str, kind: str, metrics: list[str],
        status: str, **kw) -> CellRecord:
    return CellRecord(key=spec_key(table, row, prefix), table=table, row=row, label=label,
                      kind=kind, metrics=metrics, status=status, **kw)


def extra(row: str, label: str, seq: str, status: str, **kw) -> CellRecord:
    return CellRecord(key=f"extra/mapping/{row}/{seq}@0.05m", table="extra", row=row,
                      label=label, kind="mapping", metrics=[], status=status,
                      inputs={"sequence": seq, "resolution": 0.05}, **kw)


def make_records() -> list[CellRecord]:
    nyu_needs = ["dataset:nyuv2", "weights:feagnet-v2@nyuv2"]
    return [
        # Table I
        rec("table1", "feagnet-v2", "complexity", "FEAGNet-V2", "complexity",
            ["params", "flops"], "ok", values={"params": 4.28e6, "flops": 7.5e9},
            notes=["fvcore FLOPs at 640x480"]),
        rec("table1", "feagnet-v2", "speed", "FEAGNet-V2", "speed", ["fps"], "ok",
            values={"fps": 20.07}, notes=["onnxruntime, 2 threads"]),
        rec("table1", "feagnet-v2", "accuracy/nyuv2", "FEAGNet-V2", "accuracy",
            ["miou_nyuv2"], "na", needs=nyu_needs, reason=needs_text(nyu_needs)),
        rec("table1", "feagnet-v1", "speed", "FEAGNet-V1", "speed", ["fps"], "error",
            error="RuntimeError: boom"),
        rec("table1", "feagnet-v1", "complexity", "FEAGNet-V1", "complexity",
            ["params", "flops"], "ok", values={"params": 4.5e6, "flops": 1.94e9}),
        rec("table1", "feagnet-v2-jetson", "speed", "FEAGNet-V2*", "speed", ["fps"], "na",
            needs=["hardware:jetson-tensorrt"],
            reason=needs_text(["hardware:jetson-tensorrt"])),
        # Table II
        rec("table2", "feagnet-s", "complexity", "FEAGNet-S", "complexity", ["params"], "ok",
            values={"params": 2.81e6}),
        rec("table2", "feagnet-s", "speed@1024", "FEAGNet-S", "speed", ["fps_1024"], "ok",
            values={"fps_1024": 30.0}),
        # Table III: one ok, one record lacking a value
        rec("table3", "full", "complexity", "Basel. + CFIM + DAPPF + WA&HA + ML", "complexity",
            ["params", "flops"], "ok", values={"params": 4.45e6, "flops": 7.85e9}),
        rec("table3", "basel", "complexity", "Basel.", "complexity", ["params", "flops"], "ok",
            values={"params": 3.3e6}),
        # Table IV
        rec("table4", "evsmap", "mapping/tum+", "MVSMMap", "mapping", ["runtime"], "ok",
            values={"runtime": 3.21}, inputs={"sequence": "synthetic"},
            notes=["segmentation + update rate measured on synthetic"]),
        rec("table4", "evsmap", "mapping/tum@", "MVSMMap", "mapping", ["size_seq1"], "na",
            needs=["weights:feagnet-v2@nyuv2"], reason="n/a - needs trained weights "
            "(feagnet-v2@nyuv2) (tum has no ground-truth labels for the oracle)"),
        rec("table4", "orgbmap", "mapping/tum+", "ORGBMap", "mapping", ["runtime"], "error",
            error="its mapping run did not run"),
        rec("table4", "orgbmap", "mapping/tum@", "ORGBMap", "mapping", ["size_seq1"], "ok",
            values={"size_seq1": 1.234e6}, inputs={"sequence": "tum"},
            notes=["36 frames of tum_fr1_xyz at 0.05 m"]),
        # beyond the paper
        extra("evsmap", "MVSMMap", "synthetic", "ok",
              values={"frames": 8.0, "update_hz": 12.5, "segment_update_hz": 3.21,
                      "map_bytes": 2.5e6, "octomap_memory_bytes": 8.1e6,
                      "rss_added_bytes": 3.42e7, "precision": 0.951,
                      "recall": 0.802, "semantic_accuracy": 0.875, "map_miou": 0.613},
              notes=["8 frames of synthetic at 0.05 m"]),
        extra("orgbmap", "ORGBMap", "synthetic", "ok",
              values={"frames": 8.0, "update_hz": 20.0, "segment_update_hz": 20.0,
                      "map_bytes": 1.9e6, "octomap_memory_bytes": 6.0e6, "precision": 0.95,
                      "recall": 0.81}),
        extra("octomap-cpp", "OctoMap (C++)", "synthetic", "ok",
              values={"frames": 8.0, "update_hz": 45.0, "segment_update_hz": 45.0,
                      "map_bytes": 1.2e6, "octomap_memory_bytes": 3.0e6}),
        extra("orgbmap", "ORGBMap", "tum", "ok",
              values={"frames": 36.0, "update_hz": 9.0, "segment_update_hz": 9.0,
                      "map_bytes": 1.234e6, "octomap_memory_bytes": 4.0e6}),
        extra("tesamap", "TESAMap", "tum", "na", needs=["weights:esanet@nyuv2"],
              reason="n/a - needs trained weights (esanet@nyuv2)"),
    ]


def write_artifacts(folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    h, w = 24, 32
    gt = rng.integers(0, 40, (h, w)).astype(np.uint8)
    gt[:3] = 255
    pred = gt.astype(np.int16)
    pred[5] = -1
    np.savez_compressed(folder / "seg-oracle-synthetic.npz",
                        rgb=rng.integers(0, 255, (h, w, 3)).astype(np.uint8), gt=gt, pred=pred,
                        title=np.str_("oracle on synthetic frame 4"))
    n = 300
    centres = rng.uniform(-2, 2, (n, 3)).astype(np.float32)
    for row, labelled in (("evsmap", True), ("orgbmap", False), ("octomap-cpp", False)):
        labels = (rng.integers(-1, 40, n) if labelled else np.full(n, -1)).astype(np.int16)
        np.savez_compressed(folder / f"map-{row}-synthetic.npz", centres=centres, labels=labels,
                            colors=rng.integers(0, 255, (n, 3)).astype(np.uint8),
                            resolution=np.float64(0.05))


def make_run(root: Path, *, records: list[CellRecord] | None = None,
             artifacts: bool = True) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    records = make_records() if records is None else records
    run = dict(RUN, cells=[r.key for r in records])
    (root / "run.json").write_text(json.dumps(run, indent=1))
    store = RecordStore(root)
    for r in records:
        store.write(r)
    if artifacts:
        write_artifacts(root / "artifacts")
    return root


@pytest.fixture(scope="module")
def built_run(tmp_path_factory):
    """A run folder with its report built once: (folder, written files)."""
    from evsmap.report import build_report

    root = make_run(tmp_path_factory.mktemp("run"))
    return root, build_report(root)
