"""Gate workloads measured in this process (the worker's phases, small budgets): counts are
exact and repeatable, the figures are sane, and each kind of job runs."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from evsmap.gate.worker import measure
from evsmap.gate.workloads import UPDATE_FRAMES, plan


@pytest.fixture
def one_thread():
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


@pytest.fixture
def tum_context(tmp_path):
    """The TUM sample and seeded random top-3 observations of the updaters' frames (any
    observations do: the workload times the update, not the network)."""
    from evsmap.testing import require_sample

    tum = require_sample("tum-fr1-xyz")
    rng = np.random.default_rng(0)
    n, h, w = len(UPDATE_FRAMES), 480, 640
    classes = rng.integers(0, 40, size=(n, h, w, 3)).astype(np.int16)
    probs = np.broadcast_to(np.float32([0.6, 0.25, 0.1]), (n, h, w, 3)).copy()
    path = tmp_path / "observations.npz"
    np.savez(path, classes=classes, probs=probs, num_classes=40)
    return {"threads": 1, "tum": str(tum), "observations": str(path), "networks": {},
            "updaters": ["multiclass-bayes"], "missing": {}}


def test_plan_names_every_kind_and_needs(tum_context):
    names = {w.name: w for w in plan({**tum_context, "networks": {"feagnet-v1": {}}})}
    assert {"net/feagnet-v1/torch", "net/feagnet-v1/onnxruntime", "update/multiclass-bayes/5cm",
            "update/multiclass-bayes/2cm", "map/feagnet-v1+multiclass-bayes", "read/tum",
            "read/rosbag", "report/build"} == set(names)
    assert names["update/multiclass-bayes/2cm"].needs == ("tum", "observations")
    assert names["read/rosbag"].needs == ("bag",)


def test_a_network_forward_counts_its_parameters_and_repeats_its_output(one_thread):
    a = measure("net/feagnet-s/torch", {"threads": 1}, budget_s=0.1, min_pairs=3, max_pairs=3)
    b = measure("net/feagnet-s/torch", {"threads": 1}, budget_s=0.1, min_pairs=3, max_pairs=3)
    assert a["counts"]["params"] == 2_758_106  # FEAGNet-S, docs/feagnet.md
    assert a["counts"]["flops"] > 1e9
    assert a["counts"] == b["counts"]  # seeded weights and inputs: the same labels
    assert a["pairs"] == 3 and a["time_ratio"] > 0 and a["threads"] == 1
    assert a["peak_rss_bytes"] > 20 * 2**20  # activations at 480x640
    assert set(a["calibration_parts_ms"]) == {"matmul", "sort"}
    assert a["allocator"] == "glibc, fixed mmap threshold"


def test_an_updater_workload_maps_the_same_tree_each_time(tum_context, one_thread):
    rec = measure("update/multiclass-bayes/5cm", tum_context, budget_s=0.1, min_pairs=2,
                  max_pairs=2)
    again = measure("update/multiclass-bayes/5cm", tum_context, budget_s=0.1, min_pairs=2,
                    max_pairs=2)
    assert rec["counts"] == again["counts"]
    c = rec["counts"]
    assert c["leaves"] > 1000 and c["nodes"] > c["leaves"] and c["file_bytes"] > 0
    assert rec["peak_rss_bytes"] > 0


def test_the_report_build_writes_the_same_tables(one_thread):
    a = measure("report/build", {"threads": 1}, budget_s=0.1, min_pairs=1, max_pairs=1)
    b = measure("report/build", {"threads": 1}, budget_s=0.1, min_pairs=1, max_pairs=1)
    assert a["counts"] == b["counts"]
    assert a["counts"]["files"] >= 10  # four tables (md + csv), extra.csv, plots, index.md


def test_the_memory_calibration_gathers_beyond_the_cache_and_the_kinds_are_planned(tum_context):
    from evsmap.gate.calibration import Calibration

    cal = Calibration("memory")
    assert cal.run() > 0 and set(cal.parts) == {"gather"}
    assert cal._table.nbytes == 64 * 2**20  # beyond a 32 MiB L3
    kinds = {w.name: w.calibration for w in plan({**tum_context, "networks": {"feagnet-v1": {}}})}
    assert kinds["update/multiclass-bayes/5cm"] == kinds["read/rosbag"] == "memory"
    assert kinds["net/feagnet-v1/torch"] == kinds["read/tum"] == "compute"
    assert kinds["report/build"] == "memory"
