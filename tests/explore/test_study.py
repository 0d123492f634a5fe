"""The study: a study interrupted and resumed holds the trials a straight run holds (the same
parameters, the same exact results, slot by slot), a trial whose worker died runs again, and the
first trial is the paper's point."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from evsmap.explore.bench import Bench
from evsmap.explore.study import (
    DEFAULT_ROLE,
    StudyConfig,
    create_study,
    enqueue_defaults,
    load_study,
    open_storage,
)
from evsmap.explore.workers import Worker, counts, fail_stale, work
from tests.explore.conftest import SMALL_INPUTS

pytestmark = pytest.mark.slow

TRIALS = 6


def _new(tmp_path: Path, name: str, space: Any) -> tuple[Any, Any]:
    storage = open_storage(f"sqlite:///{tmp_path / name}.db")
    config = StudyConfig(space.text, space.path, SMALL_INPUTS.as_dict(), TRIALS)
    return storage, create_study(storage, "explore", space, config)


def _by_slot(study: Any) -> dict[int, dict[str, Any]]:
    out = {}
    for t in study.get_trials(deepcopy=False):
        if t.state.name == "COMPLETE":
            record = t.user_attrs["record"]
            out[t.user_attrs["slot"]] = {"params": t.params, "map_size": record["map_size"],
                                         "scene_miou": record["scene_miou"],
                                         "size_ratio": record["size_ratio"]}
    return out


class _StopAt(Bench):
    """A bench that is interrupted (as by Ctrl-C) in its ``stop``-th measurement."""

    stop = 4

    def measure(self, params: dict[str, Any]) -> dict[str, Any]:
        self.stop -= 1
        if self.stop == 0:
            raise KeyboardInterrupt
        return super().measure(params)


def test_resumed_study_equals_a_straight_one(tmp_path: Path, small_space) -> None:
    storage, straight = _new(tmp_path, "straight", small_space)
    bench = Bench(small_space, SMALL_INPUTS)
    assert work(straight, storage, bench, trials=TRIALS, worker=Worker.here()) == TRIALS

    storage_b, broken = _new(tmp_path, "broken", small_space)
    with pytest.raises(KeyboardInterrupt):
        work(broken, storage_b, _StopAt(small_space, SMALL_INPUTS), trials=TRIALS,
             worker=Worker.here())
    assert counts(broken) == {"COMPLETE": 3, "FAIL": 1}
    resumed = load_study(storage_b, "explore")  # a new process: a fresh sampler
    assert work(resumed, storage_b, Bench(small_space, SMALL_INPUTS), trials=TRIALS,
                worker=Worker.here()) == TRIALS - 3
    assert counts(resumed) == {"COMPLETE": TRIALS, "FAIL": 1}

    a, b = _by_slot(straight), _by_slot(resumed)
    assert sorted(a) == list(range(TRIALS)) == sorted(b)
    assert a == b  # the parameters drawn and the exact results, slot by slot
    # the failed trial's draw is the one its slot got again
    failed = next(t for t in resumed.trials if t.state.name == "FAIL")
    assert failed.params == b[failed.user_attrs["slot"]]["params"]
    # the sampler went beyond its random start: later draws depend on the stored results
    first = next(t for t in resumed.trials if t.user_attrs.get("slot") == 0)
    assert first.user_attrs.get("role") == DEFAULT_ROLE
    assert first.params == small_space.defaults()


def test_a_trial_whose_process_died_runs_again(tmp_path: Path, small_space) -> None:
    storage, study = _new(tmp_path, "stale", small_space)
    trial = study.ask()  # the paper's point, taken by a process that then died
    trial.set_user_attr("worker", {"host": Worker.here().host, "pid": 2**22 + 12345,
                                   "run": "gone"})
    assert counts(study) == {"RUNNING": 1}
    assert fail_stale(study, storage) == [trial.number]
    assert counts(study) == {"FAIL": 1}
    enqueue_defaults(study, small_space)  # as a resumed study does
    done = work(study, storage, Bench(small_space, SMALL_INPUTS), trials=2,
                worker=Worker.here())
    assert done == 2
    rerun = [t for t in study.trials if t.state.name == "COMPLETE"
             and t.user_attrs.get("role") == DEFAULT_ROLE]
    assert len(rerun) == 1 and rerun[0].params == small_space.defaults()


def test_an_unclaimed_trial_is_failed_after_the_grace_period(tmp_path: Path, small_space,
                                                              monkeypatch) -> None:
    """A process stopped inside ``ask`` leaves a running trial without a worker: failed once
    no worker claimed it for the grace period, not before."""
    import evsmap.explore.workers as workers

    storage, study = _new(tmp_path, "unclaimed", small_space)
    trial = study.ask()
    assert fail_stale(study, storage) == []
    monkeypatch.setattr(workers, "GRACE_S", 0)
    assert fail_stale(study, storage) == [trial.number]
    assert study.trials[0].user_attrs["failed_because"] == "no worker claimed it"


def test_a_live_trial_of_this_host_is_left_alone(tmp_path: Path, small_space) -> None:
    storage, study = _new(tmp_path, "live", small_space)
    trial = study.ask()
    trial.set_user_attr("worker", Worker.here().as_dict())  # this process: alive
    assert fail_stale(study, storage) == []
    assert counts(study) == {"RUNNING": 1}


def test_trial_record_holds_the_ratios(tmp_path: Path, small_space) -> None:
    storage, study = _new(tmp_path, "record", small_space)
    work(study, storage, Bench(small_space, SMALL_INPUTS), trials=1, worker=Worker.here())
    record = study.trials[0].user_attrs["record"]
    assert record["rate_ratio"] == pytest.approx(
        record["update_hz"] / record["reference"]["update_hz"])
    assert record["size_ratio"] == pytest.approx(
        record["baseline"]["map_size"] / record["map_size"])
    assert record["miou_loss"] == pytest.approx(
        100 * (record["baseline"]["scene_miou"] - record["scene_miou"]))
    assert record["map_size"] == record["octomap_memory_bytes"]  # Table IV's reading
    assert record["baseline"]["row"] == "tesamap"
    assert study.trials[0].values == [record["map_size"], record["scene_miou"]]
