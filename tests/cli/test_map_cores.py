"""``evsmap map --cores N`` plans the pipelined loop's threads for N cores and records the plan
(``thread_plan``) and how near the loop came to its slowest stage (``loop``); a map made with
the 16-core plan on this machine is the 2-core plan's, byte for byte."""

from __future__ import annotations

import json
import os

import pytest

from evsmap.cli.main import main
from evsmap.measure.pipelined import PIPELINED

GEOMETRY = ["--updater", "orgb", "--frames", "2"]


def map_json(capsys, sequence, *args: str) -> dict:
    assert main(["map", str(sequence), *GEOMETRY, *args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def planned(record: dict) -> dict:
    return {k: v["threads"] for k, v in record["thread_plan"]["stages"].items()}


@pytest.mark.parametrize("cores, torch, update", [(2, 1, 1), (4, 2, 1), (16, 10, 5)])
def test_the_plan_for_the_cores_given_is_printed_and_applied(capsys, tum_dir, cores, torch,
                                                             update):
    record = map_json(capsys, tum_dir, "--cores", str(cores))
    plan = record["thread_plan"]
    assert (plan["cores"], plan["cores_from"], plan["device"], plan["loop"]) == \
        (cores, "--cores", "cpu", "pipelined")
    assert planned(record) == {"read": 1, "segment": None, "torch": torch, "update": update,
                               "blas": 1}
    assert record["pipeline"]["segment"]["torch"] == torch  # what the loop ran with
    assert record["pipeline"]["update"]["numba"] == min(update, len(os.sched_getaffinity(0)))


def test_two_cores_plan_todays_pipelined_threads(capsys, tum_dir):
    stages = map_json(capsys, tum_dir, "--cores", "2")["thread_plan"]["stages"]
    assert [stages[k]["threads"] for k in ("segment", "torch", "update", "blas")] == \
        [PIPELINED.segment, PIPELINED.torch, PIPELINED.update, PIPELINED.blas]


def test_without_cores_the_plan_is_for_the_processs_cpus(capsys, tum_dir):
    plan = map_json(capsys, tum_dir)["thread_plan"]
    assert plan["cores"] == len(os.sched_getaffinity(0))
    assert plan["cores_from"].startswith("this process's CPUs")


def test_stage_threads_override_the_plan(capsys, tum_dir):
    record = map_json(capsys, tum_dir, "--cores", "16", "--stage-threads", "torch=3")
    assert planned(record)["torch"] == 3 and planned(record)["update"] == 5
    assert record["thread_plan"]["stages"]["torch"]["reason"].startswith(
        "--stage-threads torch=3 (the plan: 10)")


def test_the_record_sets_the_wall_rate_beside_the_slowest_stage(capsys, tum_dir):
    record = map_json(capsys, tum_dir, "--cores", "4")
    loop = record["loop"]
    assert loop["bound"] in ("read", "update")  # no segmenter runs for orgb
    assert loop["bound_ms"] == max(record["stage_ms_median"]["read"],
                                   record["stage_ms_median"]["update"])
    assert loop["reached"] == pytest.approx(record["wall_hz"] * loop["bound_ms"] / 1000)
    assert set(loop["shares"]) == set(record["stage_ms_median"])


def test_the_text_report_says_the_plan_and_the_share_of_the_bound(capsys, tum_dir):
    assert main(["map", str(tum_dir), *GEOMETRY, "--cores", "16"]) == 0
    lines = {line[:12].strip(): line[13:] for line in capsys.readouterr().out.splitlines()}
    assert lines["loop"].startswith("reaches ") and "of its slowest stage's rate" in \
        lines["loop"]
    assert " of the wall time a frame (the stages overlap)" in lines["shares"]
    assert lines["threads"] == ("segment default, torch 10, update 5, blas 1 (pipelined loop "
                                "planned for 16 cores, --cores; network on cpu)")


@pytest.mark.parametrize("value, message", [
    ("0", "argument --cores: expected a positive integer, got '0'"),
    ("four", "argument --cores: expected a positive integer, got 'four'"),
    ("2000", "--cores 2000: plan for 1 to 1024 cores, please"),
])
def test_a_bad_core_count_is_one_line_and_exit_2(capsys, tum_dir, value, message):
    try:  # argparse's refusals exit, the command's return
        code = main(["map", str(tum_dir), *GEOMETRY, "--cores", value])
    except SystemExit as exit_:
        code = exit_.code
    assert code == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


@pytest.mark.slow
def test_the_16_core_plan_writes_the_2_core_plans_map(tum_dir, tmp_path):
    """FEAGNet-V1 on the TUM sample: the 16-core plan runs the pre- and post-processing on 10
    torch threads and the update on 5 (as many as numba has here), the 2-core plan on 1."""
    maps = []
    for cores in ("2", "16"):
        out = tmp_path / f"{cores}.ot"
        assert main(["map", str(tum_dir), "--updater", "classic-semantic", "--segmenter",
                     "feagnet-v1", "--allow-random", "--frames", "3", "--cores", cores,
                     "--out", str(out)]) == 0
        maps.append(out.read_bytes())
    assert maps[0] == maps[1]
