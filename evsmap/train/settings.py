"""The settings of a training run that ``--resume`` repeats.

A run records in ``run.json`` (``"settings"``) what it was asked to train and how: the model and
its options, the dataset (an absolute path where it is a folder), reader, reader options, splits
and ``--limit``, the device's kind, ``--channels-last``, ``--deterministic`` and the intra-op
thread count. ``evsmap train --out DIR --resume`` takes every setting it is not given from
there, so a resumed run needs no other flag and computes what the straight run computes; a flag
given on resume that says otherwise is refused in one line (the recipe's own fields are checked
against the checkpoint's recipe: :func:`evsmap.train.setup.choose_recipe`).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from evsmap.errors import EvsmapError
from evsmap.train.checkpoint import CHECKPOINT, RUN, load_checkpoint
from evsmap.train.options import RunOptions

FLAGS = {"model": "MODEL", "options": "-o", "dataset": "--dataset", "reader": "--reader",
         "reader_options": "-r", "train_split": "--train-split", "val_split": "--val-split",
         "limit": "--limit", "device": "--device", "channels_last": "--channels-last",
         "deterministic": "--deterministic", "threads": "--threads"}
"""The settings a resume repeats (fields of :class:`~evsmap.train.options.RunOptions`) and the
flag that gives each."""

_LEGACY = ("model", "options", "dataset", "reader", "train_split", "val_split", "device",
           "channels_last", "deterministic")
"""The settings a ``run.json`` without ``"settings"`` holds at its top level."""


def settings_record(opts: RunOptions, device_type: str, threads: int) -> dict[str, Any]:
    """``run.json``'s ``"settings"``: ``opts`` as a resume applies them (the dataset as an
    absolute path where it is one, the device's kind, the thread count the run used)."""
    dataset = Path(opts.dataset)
    return {"model": opts.model, "options": _plain(dict(opts.options)),
            "dataset": str(dataset.resolve()) if dataset.exists() else opts.dataset,
            "reader": opts.reader, "reader_options": _plain(_pairs(opts.reader_options)),
            "train_split": opts.train_split, "val_split": opts.val_split, "limit": opts.limit,
            "device": device_type, "channels_last": opts.channels_last,
            "deterministic": opts.deterministic, "threads": threads}


def recorded_settings(out: Path) -> dict[str, Any] | None:
    """The settings of the run in ``out``: ``run.json``'s (the checkpoint's copy of it when
    ``run.json`` is missing); None when the folder holds no run. A run recorded before
    ``"settings"`` existed gives those its record has."""
    path, ckpt = out / RUN, out / CHECKPOINT
    if path.is_file():
        try:
            record = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise EvsmapError(f"{path}: unreadable ({exc}): it records the run's settings "
                              f"that --resume repeats") from None
    elif ckpt.is_file():
        record = load_checkpoint(ckpt)["run"]
    else:
        return None
    if not isinstance(record, dict):
        raise EvsmapError(f"{path}: not a run's record (a JSON object)")
    settings = record.get("settings")
    if isinstance(settings, dict):
        return settings
    return {key: record[key] for key in _LEGACY if key in record}


def with_recorded_settings(opts: RunOptions) -> RunOptions:
    """``opts`` completed for the run it names: a new run must name a model and a dataset; a
    resumed one takes each setting it was not given from the run's record.

    Raises:
        EvsmapError: a new run without a model or dataset; a flag that conflicts with the
            recorded run (one line naming the flag, both values and what to do).
    """
    if not opts.resume:
        if not opts.model or not opts.dataset:
            raise EvsmapError("a new run needs MODEL and --dataset (only --resume takes them "
                              "from the run in --out)")
        return opts
    recorded = recorded_settings(Path(opts.out))
    if recorded is None:
        return opts  # nothing to resume: the set-up says so
    changes: dict[str, Any] = {}
    for key, flag in FLAGS.items():
        if key not in recorded:
            continue
        given, value = getattr(opts, key), recorded[key]
        if _unset(given):
            changes[key] = _as_option(key, value)
        elif not _same(key, given, value):
            raise EvsmapError(f"{opts.out} {_conflict(key, flag, given, value)}: a resumed run "
                              f"keeps its settings (leave out {flag})")
    return dataclasses.replace(opts, **changes)


def _conflict(key: str, flag: str, given: Any, value: Any) -> str:
    """How a given setting contradicts the recorded one, in words."""
    if key == "model":
        return f"is a run of {value}, not {given}"
    if isinstance(given, bool):
        return f"was trained {'without' if value is False else 'with'} {flag}"
    return f"was trained with {flag} {_shown(value)}, not {_shown(given)}"


def _unset(value: Any) -> bool:
    """Whether a setting was left out (its default: empty, None or False)."""
    return value is None or value is False or (not isinstance(value, (int, float)) and
                                               not value)


def _same(key: str, given: Any, value: Any) -> bool:
    if key == "dataset":
        path = Path(given)
        return (str(path.resolve()) if path.exists() else given) == value
    if key == "device":
        return str(given).split(":")[0] == value
    if key == "reader_options":
        return _plain(_pairs(given)) == value
    if key == "options":
        return _plain(dict(given)) == value
    return bool(given == value)


def _as_option(key: str, value: Any) -> Any:
    """A recorded setting as :class:`RunOptions` holds it."""
    if key == "reader_options":
        return [tuple(pair) for pair in value]
    if key == "threads" and (isinstance(value, bool) or not isinstance(value, int)
                             or value < 1):
        raise EvsmapError(f"the run's record gives threads {value!r}: not a positive integer")
    return value


def _pairs(pairs: Any) -> list[list[Any]]:
    return [list(pair) for pair in pairs]


def _plain(value: Any) -> Any:
    """``value`` as JSON gives it back (tuples as lists), to compare with a record."""
    return json.loads(json.dumps(value, default=str))


def _shown(value: Any) -> str:
    if isinstance(value, dict):
        return " ".join(f"{k}={v}" for k, v in value.items()) or "(none)"
    if isinstance(value, list):
        return " ".join(f"{k}={v}" for k, v in value) or "(none)"
    return "(none)" if value is None else str(value)


__all__ = ["FLAGS", "recorded_settings", "settings_record", "with_recorded_settings"]
