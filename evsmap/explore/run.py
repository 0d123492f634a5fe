"""Running a study: make or resume it (:func:`open_study`), then its trials on this machine
(:func:`run_local`, the machine's one timing slot: trials are timed one at a time) or on a Ray
cluster (:func:`run_ray`, one worker per timing node, each in a fresh interpreter, all sharing
the study's storage), with progress on a terminal."""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from evsmap.explore.bench import Bench, Inputs
from evsmap.explore.space import Space
from evsmap.explore.study import (
    ATTR,
    StudyConfig,
    StudyError,
    create_study,
    enqueue_defaults,
    load_study,
    open_storage,
    space_of,
    stored_config,
)
from evsmap.explore.workers import Worker, counts, fail_stale, fail_trials, work

if TYPE_CHECKING:
    import optuna


INPUT_OPTIONS = {"sequence": "--sequence", "reader": "--reader", "reader_options": "-r",
                 "frames": "--frames", "segmenter": "--segmenter", "segmenter_options": "-s",
                 "weights": "--weights"}
"""The command-line option of each :class:`~evsmap.explore.bench.Inputs` field."""


@dataclass(frozen=True)
class Request:
    """What ``evsmap explore`` was asked.

    Attributes:
        out: the study folder.
        storage: the storage URL.
        study: the study's name in it.
        trials: the target number of complete trials (``None`` on resume: the stored one).
        resume: continue the study in the storage (else make it; it must not exist).
        space: the space (``None`` on resume: the stored one; given, it must be the same).
        inputs: what the trials map (on resume: the stored ones).
        inputs_given: the input fields given on the command line (checked on resume).
    """

    out: Path
    storage: str
    study: str
    trials: int | None
    resume: bool
    space: Space | None = None
    inputs: Inputs = field(default_factory=Inputs)
    inputs_given: tuple[str, ...] = ()


@dataclass
class Opened:
    """An open study: its storage, the study, its space and what it was made with; ``target``
    the complete trials this command runs it to (0: none, the report only)."""

    storage: Any
    study: optuna.Study
    space: Space
    config: StudyConfig
    target: int = 0


def open_study(request: Request) -> Opened:
    """The study ``request`` names, made or resumed (:class:`StudyError` where it cannot be:
    nothing stored is changed then)."""
    storage = open_storage(request.storage)
    if not request.resume:
        assert request.space is not None and request.trials is not None
        config = StudyConfig(request.space.text, request.space.path, request.inputs.as_dict(),
                             request.trials)
        study = create_study(storage, request.study, request.space, config)
        return Opened(storage, study, request.space, config, request.trials)
    study = load_study(storage, request.study)
    config = stored_config(study)
    space = space_of(config)
    if request.space is not None and request.space.text != config.space_text:
        raise StudyError(f"--space {request.space.path}: not the space study "
                         f"{request.study!r} was made with ({config.space_path}); leave "
                         f"--space out to resume it")
    for name in request.inputs_given:
        given, stored = getattr(request.inputs, name), config.inputs.get(name)
        if given != stored:
            raise StudyError(f"{INPUT_OPTIONS[name]}: the study was made with "
                             f"{stored!r}, not {given!r}; leave it out to resume")
    if request.trials and request.trials != config.trials:  # 0: the report only
        config = StudyConfig(config.space_text, config.space_path, config.inputs,
                             request.trials)
        study.set_user_attr(ATTR, config.as_dict())
    fail_stale(study, storage)
    enqueue_defaults(study, space)
    return Opened(storage, study, space, config,
                  config.trials if request.trials is None else request.trials)


class Progress:
    """Trials done, the best size ratio so far and the time left, on a terminal; nothing on a
    pipe."""

    def __init__(self, total: int, done: int, workers: int = 1) -> None:
        from tqdm import tqdm

        self.total, self.start_done, self.workers = total, done, workers
        self.started = time.monotonic()
        self.bar = tqdm(total=total, initial=done, desc="trials", unit="trial", leave=False,
                        disable=not sys.stderr.isatty(), file=sys.stderr,
                        bar_format="{desc}: {n}/{total} |{bar}| {elapsed}{postfix}")

    def update(self, study: optuna.Study) -> None:
        from evsmap.explore.results import answer, trial_rows

        rows = trial_rows(study)
        done = sum(r["state"] == "COMPLETE" for r in rows)
        found = answer(rows)
        best = (f"best smaller map {found.best['size_ratio']:.2f}x" if found.best
                else "no smaller map yet" if found.paired else "")
        elapsed = time.monotonic() - self.started
        new = done - self.start_done
        left = (self.total - done) * elapsed / new if new > 0 else math.nan
        eta = (f"~{int(left) // 60}:{int(left) % 60:02d} left" if math.isfinite(left)
               else "time left: after a trial")
        self.bar.n = done
        self.bar.set_postfix_str(f"{best}; {eta}" if best else eta, refresh=True)

    def close(self) -> None:
        self.bar.close()


def run_local(opened: Opened, *, say: Callable[[str], None], run: str,
              bench: Bench | None = None) -> int:
    """The study's trials in this process until its target; the number completed here.
    ``bench``: the trials' bench when the caller made it already (to check the inputs before
    the study was made)."""
    if bench is None:
        bench = Bench(opened.space, Inputs(**opened.config.inputs), say=say)
    n = counts(opened.study)
    if n.get("COMPLETE", 0) >= opened.target:
        return 0
    progress = Progress(opened.target, n.get("COMPLETE", 0))
    try:
        progress.update(opened.study)
        return work(opened.study, opened.storage, bench, trials=opened.target,
                    worker=Worker.here(run), on_trial=lambda _: progress.update(opened.study))
    finally:
        progress.close()


def remote_worker(url: str, name: str, run: str, target: int) -> dict[str, Any]:
    """A Ray worker: open the study from its storage and run trials until it holds
    ``target`` complete ones."""
    opened_storage = open_storage(url)
    study = load_study(opened_storage, name)
    config = stored_config(study)
    bench = Bench(space_of(config), Inputs(**config.inputs))
    done = work(study, opened_storage, bench, trials=target, worker=Worker.here(run))
    return {"completed": done}


def run_ray(opened: Opened, *, address: str | None, out: Path, say: Callable[[str], None],
            run: str) -> int:
    """The study's trials on a Ray cluster: one worker per timing node, each alone on its node
    in a fresh interpreter, sharing the storage; progress polled from the storage. An
    interruption cancels the workers and marks their running trials failed."""
    from evsmap.runner.context import RunContext
    from evsmap.runner.ray_executor import RayExecutor

    with RayExecutor(address=address) as executor:
        executor.prepare(RunContext(out=str(out)))
        say(executor.summary())
        slots = executor.timing_slots()
        n = counts(opened.study)
        if n.get("COMPLETE", 0) >= opened.target:
            return 0
        progress = Progress(opened.target, n.get("COMPLETE", 0), len(slots))
        pools = [executor.fresh(slot) for slot in slots]
        try:
            futures = [pool.submit(remote_worker, opened.storage.url, opened.study.study_name,
                                   run, opened.target) for pool in pools]
            while not all(f.done() for f in futures):
                time.sleep(1.0)
                progress.update(opened.study)
            completed = sum(int(f.result()["completed"]) for f in futures)
        except BaseException:
            for pool in pools:
                pool.shutdown(wait=False, cancel_futures=True)
            fail_trials(opened.study, opened.storage, lambda w: w.get("run") == run)
            raise
        finally:
            progress.close()
    return completed
