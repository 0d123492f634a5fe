"""The gate on a GPU, as far as a machine without one can check it: the GPU's workloads and
their calibration, a GPU kind apart from its host's CPU kind (whose id does not move), and the
Ray timing nodes grouped by GPU model."""

from __future__ import annotations

from evsmap.gate.baseline import describe_machine, machine_kind
from evsmap.gate.workloads import plan
from evsmap.runner.ray_executor import timing_nodes

CONTEXT = {"networks": {"feagnet-v1": {}, "esanet-r34-nbt1d": {}}, "updaters": ["orgb"]}


def test_on_a_gpu_the_gate_times_each_network_there_against_a_gpu_calibration():
    gpu = plan({**CONTEXT, "device": "cuda:0"})
    assert [w.name for w in gpu] == ["net/esanet-r34-nbt1d/torch", "net/feagnet-v1/torch"]
    assert {w.calibration for w in gpu} == {"gpu"} and all("cuda:0" in w.description
                                                            for w in gpu)
    cpu = plan({**CONTEXT, "device": "cpu"})
    assert [w.name for w in cpu] == [w.name for w in plan(CONTEXT)]
    assert "gpu" not in {w.calibration for w in cpu} and len(cpu) > len(gpu)


def test_a_gpu_kind_is_its_own_and_the_cpu_kind_keeps_its_id():
    machine = {"cpu": "AMD EPYC", "cpus": 2, "machine": "x86_64",
               "instruction_set": "avx512-vnni", "cpu_flags": ["avx2"], "python": "3.11.7",
               "versions": {"torch": "2.13.0", "onnxruntime": "1.32.0", "numpy": "2.3"}}
    h200 = {"gpu": "NVIDIA H200", "cuda": "12.8", "cudnn": 91000,
            "driver_version": "570.86.15", "clocks_max_sm": "1980", "clocks_sm": "1500"}
    cpu_kind = machine_kind(machine)
    gpu_kind = machine_kind({**machine, "gpu": h200})
    assert gpu_kind != cpu_kind
    assert machine_kind({**machine, "gpu": {**h200, "clocks_sm": "345"}}) == gpu_kind
    assert machine_kind({**machine, "gpu": {**h200, "gpu": "NVIDIA A100"}}) != gpu_kind
    assert machine_kind({**machine, "gpu": {}}) == cpu_kind
    assert describe_machine({**machine, "gpu": h200}).endswith(", NVIDIA H200")


def test_ray_timing_nodes_are_alike_in_their_gpu_too():
    nodes = [{"cpu": "x", "cpus": 16, "head": False, "gpu": "NVIDIA A100"},
             {"cpu": "x", "cpus": 16, "head": False, "gpu": "NVIDIA H200"},
             {"cpu": "x", "cpus": 16, "head": False, "gpu": "NVIDIA H200"}]
    assert [n["gpu"] for n in timing_nodes(nodes)] == ["NVIDIA H200", "NVIDIA H200"]
    nodes[0]["head"] = True
    assert timing_nodes(nodes) == [nodes[0]]
