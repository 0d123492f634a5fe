"""The machine facts (:mod:`evsmap.environment`): the instruction set read once, through CPUID,
and carried by every record, card and baseline."""

from __future__ import annotations

import platform

import pytest

from evsmap import environment
from evsmap.environment import cpu_flags, describe, instruction_set, int8_exact

AVX2 = ("sse4_2", "avx", "avx2", "fma")
AVX512 = (*AVX2, "avx512f", "avx512bw")


@pytest.mark.parametrize("flags, name", [
    ((*AVX512, "avx512_vnni", "avx512_bf16"), "avx512-vnni"),
    ((*AVX512, "avx512_vnni", "amx_int8"), "avx512-amx"),
    (AVX512, "avx512"),
    ((*AVX2, "avx_vnni"), "avx2-vnni"),
    (AVX2, "avx2"),
    (("sse4_2", "avx", "avx2"), "avx"),  # AVX2 without FMA: no library's AVX2 kernels
    (("sse4_2",), "sse4.2"),
    (("asimd", "asimddp"), "arm64-dotprod"),
    (("asimd",), "arm64-neon"),
    (("avx512f",), "x86_64"),  # AVX-512F alone (Knights Landing-like): not a set we name
])
def test_instruction_set_names_the_widest_set(monkeypatch, flags, name):
    monkeypatch.setattr(platform, "machine", lambda: "x86_64")
    assert instruction_set(flags) == name


def test_int8_exactness_follows_vnni():
    assert int8_exact("avx512-vnni") and int8_exact("avx2-vnni") and int8_exact("avx512-amx")
    assert int8_exact("arm64-neon")
    assert not int8_exact("avx2") and not int8_exact("avx512") and not int8_exact("sse4.2")


def test_flags_come_from_cpuid_not_the_kernel_file(monkeypatch):
    """Under an emulator /proc/cpuinfo is the host's: the flags NumPy's dispatcher reads
    through CPUID win, and only the two it does not know come from the file."""
    proc = {"avx2", "fma", "avx512f", "avx512bw", "avx512_vnni", "avx_vnni", "sse4_2"}
    monkeypatch.setattr(environment, "_proc_flags", lambda: proc)
    monkeypatch.setattr(environment, "_numpy_features",
                        lambda: {"SSE42": True, "AVX": True, "AVX2": True, "FMA3": True,
                                 "AVX512F": False, "AVX512VNNI": False})
    cpu_flags.cache_clear()
    try:
        assert cpu_flags() == ("sse4_2", "avx", "avx2", "fma", "avx_vnni")
        assert instruction_set() == "avx2-vnni"
    finally:
        cpu_flags.cache_clear()


def test_describe_carries_the_instruction_set():
    d = describe()
    assert d["instruction_set"] == instruction_set() and d["cpu_flags"] == list(cpu_flags())
    assert d["cpu"] and d["cpus"] >= 1


def test_every_machine_record_uses_the_one_collector():
    from evsmap.gate.baseline import machine_info
    from evsmap.runner.cell_base import environment as cell_environment
    from evsmap.segmenters.cards import make_card

    isa = instruction_set()
    assert cell_environment(1)["instruction_set"] == isa
    info = machine_info(1)
    assert info["instruction_set"] == isa and info["cpu_flags"] == list(cpu_flags())
    card = make_card(model="m", options={}, num_classes=1, class_names=["a"], state_dict={})
    assert card["machine"]["instruction_set"] == isa


def test_the_machine_kind_changes_with_the_instruction_set():
    from evsmap.gate.baseline import machine_info, machine_kind

    info = machine_info(1)
    assert machine_kind(info) == info["kind"]
    assert machine_kind({**info, "instruction_set": "another"}) != info["kind"]


def test_one_record_one_key_per_fact():
    from evsmap.environment import collect_environment, library_versions
    from evsmap.gitinfo import head_commit
    from evsmap.runner.cell_base import environment as cell_environment
    from evsmap.runner.ray_executor import _probe
    from evsmap.segmenters.cards import make_card

    env = collect_environment(3)
    assert list(env) == ["python", "machine", "cpu", "cpus", "instruction_set", "cpu_flags",
                         "threads", "host", "versions", "git_commit"]
    assert env["threads"] == 3 and env["versions"] == library_versions()
    assert "python" not in env["versions"] and env["git_commit"] == head_commit()
    # a record, a weights card and a Ray node name the same commit and CPU
    record = cell_environment(3)
    card = make_card(model="m", options={}, num_classes=1, class_names=["a"], state_dict={})
    probe = _probe([])
    assert record["git_commit"] == card["git_commit"] == probe["git_commit"] == head_commit()
    assert record["cpu"] == card["machine"]["cpu"] == probe["cpu"] == env["cpu"]


def test_stored_records_are_read_with_the_current_keys():
    from evsmap.environment import read_environment

    old_gate = {"cpu": "X", "python": "3.11.7", "torch": "2.0", "numpy": "2.4", "kind": "k"}
    assert read_environment(old_gate) == {"cpu": "X", "python": "3.11.7", "kind": "k",
                                          "versions": {"torch": "2.0", "numpy": "2.4"}}
    assert read_environment({"cpu_model": "X", "node": "h"}) == {"cpu": "X", "host": "h"}
    assert read_environment({"cpu": "new", "cpu_model": "old"}) == {"cpu": "new"}
    assert read_environment({"cpu": "X", "versions": {"numba": "1"}}) == {
        "cpu": "X", "versions": {"numba": "1"}}


def test_the_machine_kind_of_a_stored_baseline_is_kept():
    """benchmarks/baseline.json is keyed by the digest of its flat, older machine facts: read
    back (and from this machine's current record) it gives the same id."""
    import json
    from pathlib import Path

    from evsmap.gate.baseline import machine_info, machine_kind, read_baseline
    from evsmap.paths import REPO_ROOT

    path = Path(REPO_ROOT) / "benchmarks" / "baseline.json"
    raw = json.loads(path.read_text())["kinds"]
    for kind, entry in read_baseline(path)["kinds"].items():
        assert machine_kind(raw[kind]["machine"]) == kind
        assert machine_kind(entry["machine"]) == kind
        assert "torch" not in entry["machine"] and entry["machine"]["versions"]["torch"]
    info = machine_info(1)
    assert "host" not in info and "git_commit" not in info
    flat = {**{k: v for k, v in info.items() if k != "versions"},
            **{k: info["versions"][k] for k in ("torch", "onnxruntime", "numpy")}}
    assert machine_kind(flat) == info["kind"]
