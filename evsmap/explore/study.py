"""The Optuna study of ``evsmap explore``: its storage, what it was made with, making and loading
it (the sampler: :mod:`evsmap.explore.sampler`; the workers: :mod:`evsmap.explore.workers`).

* Storage: Optuna's RDB storage, an SQLite file in the study folder by default or any
  SQLAlchemy URL (several machines share one study through PostgreSQL, or one SQLite file on a
  shared disk). The study keeps what it was made with (the space's text, the inputs, the
  target number of trials) in its user attributes: a resumed study is checked against them.
* The paper's defaults are the study's first trial (enqueued; again after it was interrupted).
* Heartbeats: every running trial records one every :data:`HEARTBEAT_S` seconds; one older than
  :data:`GRACE_S` marks its worker dead (:func:`evsmap.explore.workers.fail_stale`).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

try:  # POSIX; elsewhere a new SQLite study is opened without the creation lock
    import fcntl
except ImportError:  # pragma: no cover
    fcntl = None  # type: ignore[assignment]

import optuna
from optuna.trial import TrialState

from evsmap.errors import EvsmapError
from evsmap.explore.sampler import DrawnPerTrial
from evsmap.explore.space import Space

STUDY_FILE = "study.db"
"""The SQLite file of a study folder's default storage."""
STUDY_NAME = "explore"
ATTR = "evsmap_explore"
"""The study's user attribute holding what it was made with."""
HEARTBEAT_S = 10
GRACE_S = 60
"""A running trial whose heartbeat is older than this is failed (another host's worker died)."""
DEFAULT_ROLE = "paper default"
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
        with _creation_lock(url):
            return optuna.storages.RDBStorage(url, engine_kwargs=kwargs,
                                              heartbeat_interval=HEARTBEAT_S,
                                              grace_period=GRACE_S)
    except Exception as exc:  # SQLAlchemy's and the drivers' errors, of many classes
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise StudyError(f"--storage {url}: cannot be opened ({reason})") from None


@contextlib.contextmanager
def _creation_lock(url: str) -> Iterator[None]:
    """Held while a SQLite study file is opened (``<file>.lock`` beside it, an exclusive
    ``flock``): Optuna makes its tables and stamps their schema version on the first opening,
    and two processes opening a new file at once (two workers, a resume, a reader) could both
    stamp it, leaving a file no later opening accepts (``UNIQUE constraint failed:
    alembic_version``; seen in CI). Other databases serialise this themselves."""
    path = Path(url[len("sqlite:///"):]) if url.startswith("sqlite:///") else None
    if fcntl is None or path is None or not path.parent.is_dir():
        yield
        return
    with open(path.with_name(path.name + ".lock"), "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


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
    from evsmap.explore.space import space_from_text

    return space_from_text(config.space_text, config.space_path)


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


