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
