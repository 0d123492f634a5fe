"""The trainer's short loop (:mod:`evsmap.train.engine`): hooks run in the order registered at
each point, ``after_train`` only when every epoch finished, ``on_exception`` instead; the
interrupt hook lets an interruption seen through compiled code go on as itself."""

from __future__ import annotations

import pytest

from evsmap.interrupt import Interrupted
from evsmap.train.engine import HookBase, TrainerBase
from evsmap.train.hooks import Interrupt


class Recorder(HookBase):
    def __init__(self, name: str, calls: list[str]) -> None:
        self.name, self.calls = name, calls

    def _add(self, point: str, trainer) -> None:
        self.calls.append(f"{self.name}.{point}@{trainer.epoch}")

    def before_train(self, trainer) -> None:
        self._add("before_train", trainer)

    def after_train(self, trainer) -> None:
        self._add("after_train", trainer)

    def before_epoch(self, trainer) -> None:
        self._add("before_epoch", trainer)

    def after_epoch(self, trainer) -> None:
        self._add("after_epoch", trainer)

    def before_step(self, trainer) -> None:
        self._add("before_step", trainer)

    def after_step(self, trainer) -> None:
        self._add("after_step", trainer)

    def on_exception(self, trainer, exc: BaseException) -> None:
        self.calls.append(f"{self.name}.on_exception:{type(exc).__name__}")


class Steps(TrainerBase):
    """Two steps an epoch; ``fail`` raises in the given epoch's first step."""

    def __init__(self, calls: list[str], fail: BaseException | None = None,
                 fail_epoch: int = -1) -> None:
        super().__init__()
        self.calls, self.fail, self.fail_epoch = calls, fail, fail_epoch

    def open_epoch(self) -> None:
        self.calls.append(f"open@{self.epoch}")

    def batches(self):
        return ["a", "b"]

    def run_step(self, batch) -> None:
        if self.fail is not None and self.epoch == self.fail_epoch:
            raise self.fail
        self.calls.append(f"step {batch}@{self.epoch}")

    def close_epoch(self) -> None:
        self.calls.append(f"close@{self.epoch}")


def test_hooks_run_in_order_at_every_point():
    calls: list[str] = []
    trainer = Steps(calls)
    trainer.register_hooks([Recorder("h1", calls), Recorder("h2", calls)])
    trainer.train(3, 4)
    assert calls == [
        "h1.before_train@3", "h2.before_train@3",
        "open@3", "h1.before_epoch@3", "h2.before_epoch@3",
        "h1.before_step@3", "h2.before_step@3", "step a@3", "h1.after_step@3", "h2.after_step@3",
        "h1.before_step@3", "h2.before_step@3", "step b@3", "h1.after_step@3", "h2.after_step@3",
        "close@3", "h1.after_epoch@3", "h2.after_epoch@3",
        "h1.after_train@4", "h2.after_train@4"]
    assert trainer.epoch == 4 and trainer.epochs_run == 1


def test_nothing_to_do_still_starts_and_ends():
    calls: list[str] = []
    trainer = Steps(calls)
    trainer.register_hooks([Recorder("h", calls)])
    trainer.train(5, 5)
    assert calls == ["h.before_train@5", "h.after_train@5"] and trainer.epochs_run == 0


def test_an_exception_skips_after_train():
    calls: list[str] = []
    trainer = Steps(calls, fail=ValueError("bad"), fail_epoch=1)
    trainer.register_hooks([Recorder("h", calls), Interrupt()])
    with pytest.raises(ValueError, match="bad"):
        trainer.train(0, 3)
    assert calls[-2:] == ["h.before_step@1", "h.on_exception:ValueError"]
    assert not any("after_train" in c for c in calls) and trainer.epoch == 1


def test_an_interruption_through_compiled_code_goes_on_as_itself():
    interrupted = Interrupted()
    try:
        raise SystemError("returned a result with an exception set") from interrupted
    except SystemError as exc:
        wrapped = exc
    calls: list[str] = []
    trainer = Steps(calls, fail=wrapped, fail_epoch=0)
    trainer.register_hooks([Recorder("h", calls), Interrupt()])
    with pytest.raises(Interrupted) as info:
        trainer.train(0, 2)
    assert info.value is interrupted
    assert calls[-1] == "h.on_exception:SystemError"
