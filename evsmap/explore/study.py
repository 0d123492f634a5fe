"""The Optuna study of ``evsmap explore``: storage, sampler, the worker loop and stale trials.

* Storage: Optuna's RDB storage, an SQLite file in the study folder by default or any
  SQLAlchemy URL (several machines share one study through PostgreSQL, or one SQLite file on a
  shared disk). The study keeps what it was made with (the space's text, the inputs, the
  target number of trials) in its user attributes: a resumed study is checked against them.
* Sampler (:class:`DrawnPerTrial`): TPE or NSGA-II, made afresh for every trial and seeded from
  the study's seed and the trial's *slot* (the trials finished or started before it), so a
  trial's parameters depend only on the seed and the stored trials: a study killed and resumed
  draws what a straight run draws. The paper's defaults are the first trial (enqueued).
* Worker loop (:func:`work`): ask, measure (:class:`~evsmap.explore.bench.Bench`), tell, until
  the study holds its target of complete trials. Each running trial carries its worker (host,
  process, run) and a heartbeat: a trial whose process is gone (this host) or whose heartbeat
  stopped (another host, :data:`GRACE_S`) is marked failed, so it is run again, never lost;
  a trial that finished is never run twice.
"""

from __future__ import annotations

import os
import socket
import threading
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import optuna
from optuna.samplers import BaseSampler
from optuna.trial import FrozenTrial, TrialState

from evsmap.errors import EvsmapError
from evsmap.explore.space import Space

if TYPE_CHECKING:
    from evsmap.explore.bench import Bench

STUDY_FILE = "study.db"
"""The SQLite file of a study folder's default storage."""
STUDY_NAME = "explore"
ATTR = "evsmap_explore"
"""The study's user attribute holding what it was made with."""
HEARTBEAT_S = 10
GRACE_S = 60
"""A running trial whose heartbeat is older than this is failed (another host's worker died)."""
DEFAULT_ROLE = "paper default"
COUNTED = "failed_in_measurement"
"""The user attribute of a trial whose measurement failed (it keeps its slot)."""
FAILURES_IN_A_ROW = 3
"""Measurements failing one after the other that stop a worker (the space is likely wrong)."""


class StudyError(EvsmapError):
    """A study that cannot be opened, made or resumed (one line, names the storage)."""


def default_storage(out: str | os.PathLike[str]) -> str:
    return f"sqlite:///{Path(out).resolve() / STUDY_FILE}"


def open_storage(url: str) -> optuna.storages.RDBStorage:
    """Optuna's RDB storage at ``url`` (heartbeats on), or :class:`StudyError`."""
    import warnings

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    # heartbeats are used on purpose outside Study.optimize (the worker loop records them)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    warnings.filterwarnings("ignore", message="Heartbeat of storage is supposed to be used")
    kwargs: dict[str, Any] = {}
    if url.startswith("sqlite"):
        kwargs = {"connect_args": {"timeout": 60}}
    try:
        return optuna.storages.RDBStorage(url, engine_kwargs=kwargs,
                                          heartbeat_interval=HEARTBEAT_S, grace_period=GRACE_S)
    except Exception as exc:  # SQLAlchemy's and the drivers' errors, of many classes
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise StudyError(f"--storage {url}: cannot be opened ({reason})") from None


@dataclass(frozen=True)
class StudyConfig:
    """What a study is made with, stored in it (:data:`ATTR`).

    Attributes:
        space_text: the space file's text (the study's space is read from it on resume).
        space_path: where it was read from, for messages.
        inputs: :class:`~evsmap.explore.bench.Inputs` as a dict.
        trials: the target number of complete trials.
    """

    space_text: str
    space_path: str
    inputs: dict[str, Any]
    trials: int

    def as_dict(self) -> dict[str, Any]:
        return {"space_text": self.space_text, "space_path": self.space_path,
                "inputs": self.inputs, "trials": self.trials}


def stored_config(study: optuna.Study) -> StudyConfig:
    raw = study.user_attrs.get(ATTR)
    if not isinstance(raw, dict):
        raise StudyError(f"study {study.study_name!r} was not made by evsmap explore")
    return StudyConfig(**raw)


def space_of(config: StudyConfig) -> Space:
    """The study's space, parsed from its stored text (and checked against the registry)."""
    import tempfile

    from evsmap.explore.space import load_space

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / Path(config.space_path).name
        path.write_text(config.space_text, encoding="utf-8")
        space = load_space(path)
    return Space(**{**space.__dict__, "path": config.space_path})


def directions(space: Space) -> list[Literal["minimize", "maximize"]]:
    return [o.direction for o in space.objectives]


def create_study(storage: optuna.storages.RDBStorage, name: str, space: Space,
                 config: StudyConfig) -> optuna.Study:
    """A new study holding ``config``, its first trial the space's defaults."""
    try:
        study = optuna.create_study(storage=storage, study_name=name,
                                    directions=directions(space),
                                    sampler=DrawnPerTrial(space))
    except optuna.exceptions.DuplicatedStudyError:
        raise StudyError(f"a study named {name!r} is already in {storage.url}: pass --resume "
                         f"to continue it, or --study NAME for another") from None
    study.set_user_attr(ATTR, config.as_dict())
    enqueue_defaults(study, space)
    return study


def load_study(storage: optuna.storages.RDBStorage, name: str) -> optuna.Study:
    """The study ``name`` in ``storage``, with a fresh seeded sampler (its space's)."""
    try:
        study = optuna.load_study(study_name=name, storage=storage)
    except KeyError:
        raise StudyError(f"no study named {name!r} in {storage.url} (nothing to resume)") \
            from None
    study.sampler = DrawnPerTrial(space_of(stored_config(study)))
    return study


def enqueue_defaults(study: optuna.Study, space: Space) -> None:
    """Queue the paper's point unless a trial at it finished, runs or waits."""
    for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.RUNNING,
                                                       TrialState.WAITING)):
        if t.user_attrs.get("role") == DEFAULT_ROLE:
            return
    study.enqueue_trial(space.defaults(), user_attrs={"role": DEFAULT_ROLE})


# ---- the sampler
def _slot(study: optuna.Study, number: int) -> int:
    """The trial's place in the study: the trials complete, running and started before it, or
    failed in their measurement (a point the updater cannot map: the next draw moves on).
    Interrupted trials and those of dead workers do not count, so a rerun takes their place and
    draws their parameters again; surplus trials do not count either."""
    slot = 0
    for t in study.get_trials(deepcopy=False):
        if t.state == TrialState.COMPLETE or (t.state == TrialState.RUNNING
                                              and t.number < number) \
                or (t.state == TrialState.FAIL and t.user_attrs.get(COUNTED)):
            slot += 1
    return slot


def make_sampler(space: Space, seed: int) -> optuna.samplers.BaseSampler:
    """The space's sampler (TPE or NSGA-II) seeded with ``seed``."""
    if space.sampler == "nsga2":
        return optuna.samplers.NSGAIISampler(seed=seed, population_size=space.population)
    return optuna.samplers.TPESampler(seed=seed, n_startup_trials=space.startup_trials,
                                      multivariate=True)


class DrawnPerTrial(BaseSampler):
    """Optuna's sampler made afresh for each trial, seeded from (the space's seed, the trial's
    slot): what it draws depends only on the seed and the stored trials, not on what this
    process drew before (a resumed study draws as a straight run does).

    Args:
        space: the study's space (its sampler, seed, population, startup trials).
    """

    def __init__(self, space: Space) -> None:
        self.space = space
        self._inner: dict[int, BaseSampler] = {}
        self.slots: dict[int, int] = {}
        self._fallback = make_sampler(space, space.seed)

    def _for(self, trial: FrozenTrial) -> BaseSampler:
        return self._inner.get(trial.number, self._fallback)

    def before_trial(self, study: optuna.Study, trial: FrozenTrial) -> None:
        slot = _slot(study, trial.number)
        self.slots[trial.number] = slot
        inner = make_sampler(self.space, (self.space.seed * 1_000_003 + slot) % 2**32)
        self._inner[trial.number] = inner
        inner.before_trial(study, trial)

    def infer_relative_search_space(self, study: optuna.Study,
                                    trial: FrozenTrial) -> dict[str, Any]:
        return dict(self._for(trial).infer_relative_search_space(study, trial))

    def sample_relative(self, study: optuna.Study, trial: FrozenTrial,
                        search_space: dict[str, Any]) -> dict[str, Any]:
        return dict(self._for(trial).sample_relative(study, trial, search_space))

    def sample_independent(self, study: optuna.Study, trial: FrozenTrial, param_name: str,
                           param_distribution: Any) -> Any:
        return self._for(trial).sample_independent(study, trial, param_name,
                                                   param_distribution)

    def after_trial(self, study: optuna.Study, trial: FrozenTrial, state: TrialState,
                    values: Sequence[float] | None) -> None:
        inner = self._inner.pop(trial.number, None)
        if inner is not None:
            inner.after_trial(study, trial, state, values)

    def reseed_rng(self) -> None:
        """Nothing to reseed: each trial's sampler is seeded from its slot."""


def suggest(trial: optuna.Trial, space: Space) -> dict[str, Any]:
    """The trial's parameters, drawn from the space."""
    params: dict[str, Any] = {}
    for p in space.parameters:
        if p.choices:
            params[p.name] = trial.suggest_categorical(p.name, list(p.choices))
        elif p.integer:
            params[p.name] = trial.suggest_int(p.name, int(p.low or 0), int(p.high or 0),
                                               log=p.log, step=int(p.step or 1))
        else:
            params[p.name] = trial.suggest_float(p.name, float(p.low or 0.0),
                                                 float(p.high or 0.0), log=p.log, step=p.step)
    return params


# ---- workers and stale trials
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


def fail_trials(study: optuna.Study, storage: optuna.storages.RDBStorage,
                dead: Callable[[dict[str, Any]], bool]) -> list[int]:
    """Mark failed the running trials whose worker ``dead`` says is gone; their numbers."""
    failed = []
    study_id = storage.get_study_id_from_name(study.study_name)
    for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        worker = t.user_attrs.get("worker")
        if not isinstance(worker, dict) or not dead(worker):
            continue
        trial_id = storage.get_trial_id_from_study_id_trial_number(study_id, t.number)
        try:
            storage.set_trial_user_attr(trial_id, "failed_because", "its worker stopped")
            if storage.set_trial_state_values(trial_id, state=TrialState.FAIL):
                failed.append(t.number)
        except optuna.exceptions.UpdateFinishedTrialError:
            pass
    return failed


def fail_stale(study: optuna.Study, storage: optuna.storages.RDBStorage) -> list[int]:
    """Fail the running trials of dead workers: on this host, those whose process is gone; on
    any host, those whose heartbeat stopped more than :data:`GRACE_S` ago."""
    host = socket.gethostname()
    failed = fail_trials(study, storage, lambda w: w.get("host") == host
                         and not _alive(int(w.get("pid", -1))))
    optuna.storages.fail_stale_trials(study)
    return failed


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
    (it runs again on resume) and propagates."""
    space = bench.space
    sampler = study.sampler
    done = failures = 0
    while True:
        fail_stale(study, storage)
        n = counts(study)
        if n.get("COMPLETE", 0) + n.get("RUNNING", 0) >= trials:
            return done
        trial = study.ask()
        slot = sampler.slots.get(trial.number) if isinstance(sampler, DrawnPerTrial) else None
        trial.set_user_attr("worker", worker.as_dict())
        trial.set_user_attr("slot", slot)
        if _slot(study, trial.number) >= trials:  # another worker took the last place
            trial.set_user_attr("surplus", True)
            study.tell(trial, state=TrialState.PRUNED)
            return done
        heartbeat = _Heartbeat(storage, trial._trial_id)
        try:
            params = suggest(trial, space)
            record = bench.measure(params)
        except BaseException as exc:
            heartbeat.stop()
            trial.set_user_attr("error", f"{type(exc).__name__}: {exc}"[:500])
            measured = isinstance(exc, EvsmapError)
            if measured:
                trial.set_user_attr(COUNTED, True)
            study.tell(trial, state=TrialState.FAIL)
            if not measured:  # an interruption (or a bug): the trial's slot is drawn again
                raise
            failures += 1
            if failures >= FAILURES_IN_A_ROW:
                raise StudyError(f"{failures} trials in a row could not be measured, the last "
                                 f"(trial {trial.number}): {exc}") from None
            continue
        heartbeat.stop()
        failures = 0
        trial.set_user_attr("record", _jsonable(record))
        values = [record.get(o.name) for o in space.objectives]
        if any(v is None for v in values):
            missing = [o.name for o, v in zip(space.objectives, values, strict=True)
                       if v is None]
            trial.set_user_attr("error", f"not measured: {', '.join(missing)}")
            study.tell(trial, state=TrialState.FAIL)
            raise StudyError(f"objective {missing[0]} cannot be measured on "
                             f"{bench.inputs.sequence} (no ground-truth voxels?)")
        frozen = study.tell(trial, [float(v) for v in values if v is not None])
        done += 1
        if on_trial is not None:
            on_trial(frozen)


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
