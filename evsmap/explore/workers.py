"""The workers of a study: the loop that asks the storage for a trial, measures it and tells
the result (:func:`work`), who runs each trial (:class:`Worker`, with a heartbeat), and the
trials of workers that died (:func:`fail_stale`): failed, so that their slot is drawn again and
nothing is lost; a finished trial is never run twice."""

from __future__ import annotations

import os
import socket
import threading
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime
from typing import TYPE_CHECKING, Any

import optuna
from optuna.trial import FrozenTrial, TrialState

from evsmap.errors import EvsmapError
from evsmap.explore.sampler import COUNTED, DrawnPerTrial, slot_of, suggest
from evsmap.explore.study import GRACE_S, HEARTBEAT_S, StudyError
from evsmap.interrupt import uninterrupted

if TYPE_CHECKING:
    from evsmap.explore.bench import Bench

FAILURES_IN_A_ROW = 3
"""Measurements failing one after the other that stop a worker (the space is likely wrong)."""


@dataclass(frozen=True)
class Worker:
    """Who runs a trial: the host, the process and the run (one ``evsmap explore``)."""

    host: str
    pid: int
    run: str

    @classmethod
    def here(cls, run: str | None = None) -> Worker:
        return cls(socket.gethostname(), os.getpid(), run or uuid.uuid4().hex[:12])

    def as_dict(self) -> dict[str, Any]:
        return {"host": self.host, "pid": self.pid, "run": self.run}


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _fail_where(study: optuna.Study, storage: optuna.storages.RDBStorage,
                stale: Callable[[FrozenTrial], str | None]) -> list[int]:
    """Mark failed the running trials ``stale`` gives a reason for (stored with the trial);
    their numbers. A trial finished meanwhile by its worker is left as it is."""
    failed = []
    study_id = storage.get_study_id_from_name(study.study_name)
    for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        because = stale(t)
        if because is None:
            continue
        trial_id = storage.get_trial_id_from_study_id_trial_number(study_id, t.number)
        try:
            storage.set_trial_user_attr(trial_id, "failed_because", because)
            if storage.set_trial_state_values(trial_id, state=TrialState.FAIL):
                failed.append(t.number)
        except optuna.exceptions.UpdateFinishedTrialError:
            pass
    return failed


def fail_trials(study: optuna.Study, storage: optuna.storages.RDBStorage,
                dead: Callable[[dict[str, Any]], bool]) -> list[int]:
    """Mark failed the running trials whose worker ``dead`` says is gone; their numbers."""
    def stale(t: FrozenTrial) -> str | None:
        worker = t.user_attrs.get("worker")
        return "its worker stopped" if isinstance(worker, dict) and dead(worker) else None

    return _fail_where(study, storage, stale)


def fail_stale(study: optuna.Study, storage: optuna.storages.RDBStorage) -> list[int]:
    """Fail the running trials of dead workers: on this host, those whose process is gone; on
    any host, those whose heartbeat stopped more than :data:`GRACE_S` ago."""
    host = socket.gethostname()
    failed = fail_trials(study, storage, lambda w: w.get("host") == host
                         and not _alive(int(w.get("pid", -1))))
    failed += _fail_unclaimed(study, storage)
    optuna.storages.fail_stale_trials(study)
    return failed


def _fail_unclaimed(study: optuna.Study, storage: optuna.storages.RDBStorage) -> list[int]:
    """Fail the running trials that no worker claimed for :data:`GRACE_S` seconds (a process
    stopped inside ``ask``, before it could name itself or beat)."""
    now = datetime.now()  # Optuna stamps trials with the local naive time

    def stale(t: FrozenTrial) -> str | None:
        started = t.datetime_start
        if "worker" in t.user_attrs or started is None or \
                (now - started).total_seconds() < GRACE_S:
            return None
        return "no worker claimed it"

    return _fail_where(study, storage, stale)


def counts(study: optuna.Study) -> dict[str, int]:
    """Trials by state name (``COMPLETE``, ``RUNNING``, ``FAIL``, ...)."""
    out: dict[str, int] = {}
    for t in study.get_trials(deepcopy=False):
        out[t.state.name] = out.get(t.state.name, 0) + 1
    return out


class _Heartbeat:
    """Records the trial's heartbeat every :data:`HEARTBEAT_S` seconds until stopped."""

    def __init__(self, storage: Any, trial_id: int) -> None:
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(storage, trial_id),
                                        daemon=True)
        self._thread.start()

    def _run(self, storage: Any, trial_id: int) -> None:
        storage.record_heartbeat(trial_id)
        while not self._stop.wait(HEARTBEAT_S):
            storage.record_heartbeat(trial_id)

    def stop(self) -> None:
        self._stop.set()


def work(study: optuna.Study, storage: optuna.storages.RDBStorage, bench: Bench, *,
         trials: int, worker: Worker,
         on_trial: Callable[[FrozenTrial], None] | None = None) -> int:
    """Run trials until the study holds ``trials`` complete ones (counting those other workers
    run); the number this worker completed. An interruption marks the running trial failed
    (its slot is drawn again on resume) and propagates."""
    done = failures = 0
    trial = None
    try:
        while (trial := _next_trial(study, storage, trials, worker)) is not None:
            record, error = _measured(study, storage, trial, bench)
            if record is None:
                failures += 1
                if failures >= FAILURES_IN_A_ROW:
                    raise StudyError(f"{failures} trials in a row could not be measured, the "
                                     f"last (trial {trial.number}): {error}")
                continue
            failures = 0
            frozen = _tell(study, trial, record, bench)
            done += 1
            if on_trial is not None:
                on_trial(frozen)
    except BaseException:
        if trial is not None:  # interrupted between ask and tell: its slot is drawn again
            _fail_running(study, trial)
        raise
    return done


def _fail_running(study: optuna.Study, trial: optuna.Trial) -> None:
    """Tell ``trial`` failed if it still runs (an interruption may come at any point)."""
    try:
        if study.get_trials(deepcopy=False)[trial.number].state == TrialState.RUNNING:
            study.tell(trial, state=TrialState.FAIL)
    except Exception:  # noqa: BLE001 - already told, or the storage is gone: the next
        pass  # worker's fail_stale fails it


def _next_trial(study: optuna.Study, storage: optuna.storages.RDBStorage, trials: int,
                worker: Worker) -> optuna.Trial | None:
    """The next trial, marked with its worker and slot; ``None`` when the study holds (or is
    running) its target."""
    fail_stale(study, storage)
    n = counts(study)
    if n.get("COMPLETE", 0) + n.get("RUNNING", 0) >= trials:
        return None
    # asked and claimed as one step: a Ctrl-C in between would leave a running trial no worker
    # claimed, which a resumed study counts as running for a minute (GRACE_S) and stops short;
    # the signal is raised once the trial carries this worker, and fails it
    trial = None
    try:
        with uninterrupted():
            trial = study.ask()
            sampler = study.sampler
            trial.set_user_attr("worker", worker.as_dict())
            trial.set_user_attr("slot", sampler.slots.get(trial.number)
                                if isinstance(sampler, DrawnPerTrial) else None)
    except BaseException:
        if trial is not None:
            _fail_running(study, trial)
        raise
    if slot_of(study, trial.number) >= trials:  # another worker took the last place
        trial.set_user_attr("surplus", True)
        study.tell(trial, state=TrialState.PRUNED)
        return None
    return trial


def _measured(study: optuna.Study, storage: optuna.storages.RDBStorage, trial: optuna.Trial,
              bench: Bench) -> tuple[dict[str, Any] | None, EvsmapError | None]:
    """The trial's record, with its heartbeat running; a measurement that fails (an
    :class:`EvsmapError`) is told failed and keeps its slot: ``(None, error)``. Anything else
    (an interruption) is told failed without keeping the slot, and propagates."""
    heartbeat = _Heartbeat(storage, trial._trial_id)
    try:
        return bench.measure(suggest(trial, bench.space)), None
    except BaseException as exc:
        trial.set_user_attr("error", f"{type(exc).__name__}: {exc}"[:500])
        if isinstance(exc, EvsmapError):
            trial.set_user_attr(COUNTED, True)
        study.tell(trial, state=TrialState.FAIL)
        if isinstance(exc, EvsmapError):
            return None, exc
        raise
    finally:
        heartbeat.stop()


def _tell(study: optuna.Study, trial: optuna.Trial, record: dict[str, Any],
          bench: Bench) -> FrozenTrial:
    """Store the record and tell the objectives' values."""
    trial.set_user_attr("record", _jsonable(record))
    values = [record.get(o.name) for o in bench.space.objectives]
    missing = [o.name for o, v in zip(bench.space.objectives, values, strict=True) if v is None]
    if missing:
        trial.set_user_attr("error", f"not measured: {', '.join(missing)}")
        study.tell(trial, state=TrialState.FAIL)
        raise StudyError(f"objective {missing[0]} was not measured on {bench.inputs.sequence}")
    return study.tell(trial, [float(v) for v in values if v is not None])


def _jsonable(value: Any) -> Any:
    """``value`` with numpy scalars as Python numbers and NaN as None (Optuna stores JSON)."""
    import math

    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, "item") and not isinstance(value, (str, bytes)):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value
