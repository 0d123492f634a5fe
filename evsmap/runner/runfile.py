"""``run.json``: what a run of ``evsmap reproduce`` is, in one validated schema.

:class:`RunFile` is the whole file: the tables and cells of the plan, what was skipped and why,
the run's context, environment and sequences, the user's systems, its timestamps and its
:class:`RunSettings` (the options ``--resume`` takes back). It is written by
:meth:`RunFile.write` and read by :meth:`RunFile.read` only, whose errors are one line naming
the file. Runs written before a key existed still load: every key has a default (a run without
``settings`` keeps at least its ``quick``; one without ``tables`` covers all of them).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from evsmap.errors import DataFormatError
from evsmap.fileio import atomic_write_text
from evsmap.tables.schema import table_ids

RUN_FILE = "run.json"
"""The run's description, in its folder."""

FIXED_SETTINGS = ("quick", "cells", "train", "proxy_models", "proxy_recipe", "precision",
                  "extended", "scannet_scenes", "scannet_step", "device", "synthetic_labels",
                  "oracle_profile")
"""Settings that decide what a run measures: a resumed run may not change them (its records
would be a mix); the others (where the data is, how many workers) may change."""


class RunSettings(BaseModel):
    """``reproduce``'s settings that ``run.json`` keeps (``settings``) and ``--resume`` takes
    back when they are not given again, with their defaults for a new run."""

    model_config = ConfigDict(extra="ignore")

    quick: bool = False
    cells: list[str] | None = None
    workers: int = Field(default=2, gt=0)
    executor: str = "local"
    address: str | None = None
    strict_timing: bool = False
    train: bool = False
    proxy_models: list[str] | None = None
    proxy_recipe: str | None = None
    precision: Literal["fp32", "int8"] = "fp32"
    data_root: Path | None = None
    weights_dir: Path | None = None
    budget: float | None = None
    extended: bool = False
    scannet_scenes: list[str] | None = None
    scannet_step: int = Field(default=10, gt=0)
    device: str = "cpu"
    synthetic_labels: Literal["oracle", "network"] = "oracle"
    oracle_profile: str | None = None
    """None: the oracle's default profile."""

    def stored(self) -> dict[str, Any]:
        """The settings the file held (by name): a run written before a setting existed does
        not hold it."""
        return {name: getattr(self, name) for name in self.model_fields_set}


class RunFile(BaseModel):
    """The whole ``run.json`` (the module notes); keys are written in this order."""

    model_config = ConfigDict(extra="ignore")

    tables: list[str] = Field(default_factory=lambda: list(table_ids()))
    quick: bool = False
    data_root: str | None = None
    weights_dir: str | None = None
    available: list[str] = []
    sequences: dict[str, dict[str, Any]] = {}
    cells: list[str] = []
    skipped: list[tuple[str, str]] = []
    context: dict[str, Any] = {}
    run: str | None = None
    started: str | None = None
    finished: str | None = None
    settings: RunSettings | None = None
    environment: dict[str, Any] = {}
    systems: list[dict[str, Any]] = []
    executor: dict[str, Any] | None = None
    train: dict[str, Any] | None = None
    precision: str | None = None
    time_accounting: dict[str, Any] | None = None

    @field_validator("tables", mode="before")
    @classmethod
    def _all_when_none(cls, value: Any) -> Any:
        return list(table_ids()) if value is None or value == [] else value

    def stored_settings(self) -> dict[str, Any]:
        """The settings the run was made with, as far as the file says (a run written before
        ``settings`` was stored: its ``quick``)."""
        return self.settings.stored() if self.settings is not None else {"quick": self.quick}

    def write(self, path: Path) -> None:
        """Write the file at ``path`` (atomically); ``executor``, ``train``, ``precision`` and
        ``time_accounting`` (:mod:`evsmap.runner.accounting`) only where set."""
        data = self.model_dump()
        for key in ("executor", "train", "precision", "time_accounting"):
            if data[key] is None:
                del data[key]
        atomic_write_text(path, json.dumps(data, indent=1, default=str))

    @classmethod
    def read(cls, path: Path) -> RunFile:
        """The file at ``path``.

        Raises:
            DataFormatError: it is missing, not JSON or not a run description; one line naming
                the file.
        """
        if not path.is_file():
            raise DataFormatError(f"{path}: missing (not a run folder of 'evsmap reproduce')")
        try:
            data = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise DataFormatError(f"{path}: unreadable run description ({exc})") from None
        except RecursionError:
            raise DataFormatError(f"{path}: unreadable run description (nested too deeply)"
                                  ) from None
        if not isinstance(data, dict):
            raise DataFormatError(f"{path}: expected a JSON object, got {type(data).__name__}")
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            first = exc.errors()[0]
            where = ".".join(str(part) for part in first["loc"]) or "run"
            raise DataFormatError(f"{path}: {where}: {first['msg']}") from None
