"""What ``evsmap train`` was asked to do: :class:`RunOptions`, shared by the loop, its set-up,
its hooks and the scoring (:mod:`evsmap.train.evaluate`)."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO


@dataclass
class RunOptions:
    """What ``evsmap train`` was asked to do (see its ``--help``).

    Attributes:
        model: registered segmenter name ("" when resuming: the run's).
        dataset: folder, prepared dataset name or path-less reader name ("" when resuming: the
            run's).
        out: the run's folder.
        recipe: shipped recipe name or TOML file; None: ``paper`` (or, resuming, the
            checkpoint's recipe).
        overrides: recipe fields set on the command line.
        options: segmenter options (``-o``).
        reader, reader_options: as ``evsmap eval``'s.
        train_split, val_split: splits of readers that have them.
        limit: first N frames of each split.
        device: ``cpu``, ``cuda`` or ``cuda:N``; None: CUDA when available.
        channels_last: the network and its inputs in channels-last memory format (NHWC; faster
            convolutions on tensor cores, and on some CPUs).
        deterministic: deterministic algorithms only (cuDNN's autotuner off; torch warns of an
            operation that has no deterministic kernel), for a resume repeating a straight run
            bit for bit on a GPU.
        threads: torch's intra-op threads for the whole run (None: torch's count when the run
            starts; resuming: the run's). Convolutions split their sums by it, so it is part
            of what a run computes.
        resume: continue the run in ``out`` from its checkpoint, with the settings recorded in
            its ``run.json`` wherever this invocation gives none
            (:mod:`evsmap.train.settings`).
        init: encoder weights to start from.
        stop_after: stop after this many epochs of this invocation.
        messages: where rank 0 writes its lines (default stdout).
    """

    model: str
    dataset: str
    out: Path
    recipe: str | None = None
    overrides: dict[str, Any] = field(default_factory=dict)
    options: dict[str, Any] = field(default_factory=dict)
    reader: str | None = None
    reader_options: list[tuple[str, object]] = field(default_factory=list)
    train_split: str | None = None
    val_split: str | None = None
    limit: int | None = None
    device: str | None = None
    channels_last: bool = False
    deterministic: bool = False
    threads: int | None = None
    resume: bool = False
    init: Path | None = None
    stop_after: int | None = None
    messages: TextIO | None = None

    def say(self, text: str) -> None:
        """Write one line to :attr:`messages` (stdout when None), flushed."""
        print(text, file=self.messages or sys.stdout, flush=True)


__all__ = ["RunOptions"]
