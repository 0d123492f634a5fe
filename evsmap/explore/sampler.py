"""The study's sampler: Optuna's TPE or NSGA-II made afresh for every trial and seeded from the
study's seed and the trial's *slot* (:func:`slot_of`), so what a trial draws depends only on
the seed and the trials stored before it - a study killed and resumed draws what a straight run
draws - and the parameters drawn from the space (:func:`suggest`)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import optuna
from optuna.samplers import BaseSampler
from optuna.trial import FrozenTrial, TrialState

from evsmap.explore.space import Space

COUNTED = "failed_in_measurement"
"""The user attribute of a trial whose measurement failed (it keeps its slot)."""


def slot_of(study: optuna.Study, number: int) -> int:
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
        slot = slot_of(study, trial.number)
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
