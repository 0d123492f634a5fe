"""``evsmap explore --executor ray``: the trials run in Ray workers (a fresh interpreter on the
timing node), sharing the study's storage with the driver, which reports them."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from tests.explore.conftest import SMALL_INPUTS

ray = pytest.importorskip("ray")


@pytest.mark.slow
def test_ray_workers_run_the_trials(tmp_path: Path, small_space) -> None:
    from evsmap.explore.run import Request, open_study, run_ray
    from evsmap.explore.study import default_storage
    from evsmap.explore.workers import counts

    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=2, include_dashboard=False, logging_level="WARNING")
    try:
        out = tmp_path / "study"
        out.mkdir()
        opened = open_study(Request(out=out, storage=default_storage(out), study="explore",
                                    trials=3, resume=False, space=small_space,
                                    inputs=SMALL_INPUTS))
        lines: list[str] = []
        done = run_ray(opened, address=None, out=out, say=lines.append, run="ray-test")
    finally:
        if started:
            ray.shutdown()
    assert done == 3 and counts(opened.study) == {"COMPLETE": 3}
    workers = {t.user_attrs["worker"]["pid"] for t in opened.study.trials}
    assert os.getpid() not in workers  # measured in the Ray worker's fresh interpreter
    assert {t.user_attrs["worker"]["run"] for t in opened.study.trials} == {"ray-test"}
    assert any(line.startswith("ray (") for line in lines)
