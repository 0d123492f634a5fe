"""The training loop as a short loop with hooks, after detectron2's ``TrainerBase``.

:meth:`TrainerBase.train` runs the epochs; a subclass says what an epoch is
(:meth:`~TrainerBase.open_epoch`, :meth:`~TrainerBase.batches`, :meth:`~TrainerBase.run_step`,
:meth:`~TrainerBase.close_epoch`), and hooks (:class:`HookBase`) do everything around it -
validation, checkpoints, the best model, messages, progress bars - called in the order they were
registered at each point::

    before_train
    for each epoch:      open_epoch, before_epoch,
                         for each batch: before_step, run_step, after_step
                         close_epoch, after_epoch
    after_train          (only when every epoch finished: not after an error or an interruption)
    on_exception         (instead, on any exception, before it goes on up)

Hooks receive the trainer as their argument (they hold no reference to it). This module imports
nothing heavy.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any, Generic, TypeVar

TrainerT = TypeVar("TrainerT", bound="TrainerBase")


class HookBase(Generic[TrainerT]):
    """Something done at fixed points of :meth:`TrainerBase.train`; every method does nothing
    unless overridden."""

    def before_train(self, trainer: TrainerT) -> None:
        """Before the first epoch."""

    def after_train(self, trainer: TrainerT) -> None:
        """After the last epoch (not called when training ends in an exception)."""

    def before_epoch(self, trainer: TrainerT) -> None:
        """After :meth:`TrainerBase.open_epoch`, before the first step of the epoch."""

    def after_epoch(self, trainer: TrainerT) -> None:
        """After :meth:`TrainerBase.close_epoch`."""

    def before_step(self, trainer: TrainerT) -> None:
        """Before each step."""

    def after_step(self, trainer: TrainerT) -> None:
        """After each step."""

    def on_exception(self, trainer: TrainerT, exc: BaseException) -> None:
        """When an exception (an interruption too) ends training; it is raised again after."""


class TrainerBase:
    """Epochs ``epoch .. end_epoch - 1`` with hooks.

    Attributes:
        epoch: the 0-based epoch running (after training: the number of epochs done).
        first_epoch: the epoch this invocation started at.
        end_epoch: the epoch it stops before.
    """

    def __init__(self) -> None:
        self._hooks: list[HookBase[Any]] = []
        self.epoch = self.first_epoch = self.end_epoch = 0

    def register_hooks(self, hooks: Sequence[HookBase[Any]]) -> None:
        """Add hooks, called after those already registered."""
        self._hooks.extend(hooks)

    @property
    def epochs_run(self) -> int:
        """Epochs finished by this invocation."""
        return self.epoch - self.first_epoch

    def train(self, first_epoch: int, end_epoch: int) -> None:
        """Run epochs ``first_epoch .. end_epoch - 1``, the hooks at each point in order."""
        self.epoch = self.first_epoch = first_epoch
        self.end_epoch = end_epoch
        hooks = self._hooks
        try:
            for hook in hooks:
                hook.before_train(self)
            while self.epoch < self.end_epoch:
                self.open_epoch()
                for hook in hooks:
                    hook.before_epoch(self)
                for batch in self.batches():
                    for hook in hooks:
                        hook.before_step(self)
                    self.run_step(batch)
                    for hook in hooks:
                        hook.after_step(self)
                self.close_epoch()
                for hook in hooks:
                    hook.after_epoch(self)
                self.epoch += 1
            for hook in hooks:
                hook.after_train(self)
        except BaseException as exc:
            for hook in hooks:
                hook.on_exception(self, exc)
            raise

    # -- what an epoch is (subclasses) ----------------------------------------------------------

    def open_epoch(self) -> None:
        """Prepare epoch :attr:`epoch` (learning rate, data order, seeds, clock)."""

    def batches(self) -> Iterable[Any]:
        """The epoch's batches."""
        return ()

    def run_step(self, batch: Any) -> None:
        """One optimisation step on ``batch``."""
        raise NotImplementedError

    def close_epoch(self) -> None:
        """Finish the epoch's figures (after its last step, before the hooks see it)."""


__all__ = ["HookBase", "TrainerBase"]
