"""Your own mapping systems beside Table IV's: ``evsmap reproduce --systems FILE``.

A TOML file lists systems, each a registered map updater with an optional registered segmenter
(any plug-in: docs/plugins.md)::

    [[systems]]
    id = "maxconf"              # the row: extra/mapping/maxconf/<sequence>@<voxel>m
    label = "Max-confidence map"
    updater = { name = "max-confidence" }
    segmenter = { name = "row-bands", options = { first_class = 10 } }

Each system maps every sequence Table IV maps, at the same voxel size and frames, through the
same mapping cell as the paper's systems (each in a fresh process, timed alone), and its records
appear in the report's extra section. Labels: a segmenter that is a network needs trained
weights (``<segmenter>@nyuv2.pt`` in ``--weights``), or stands in for the oracle's labels on
a labelled sequence and is only timed, exactly as for Table IV's systems; a segmenter that is not
a network (no torch module: it needs no weights) supplies its own labels.

The file is checked before anything runs: unknown keys, unknown plug-in names, options a
factory refuses and ids that clash are each one line naming the file.
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Set
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from evsmap.errors import EvsmapError
from evsmap.tables.schema import Component

ID = re.compile(r"[a-z0-9][a-z0-9_.-]*")


class _PluginModel(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: str
    options: dict[str, Any] = Field(default_factory=dict)


class _SystemModel(BaseModel):
    model_config = ConfigDict(extra="forbid")

    id: str
    label: str | None = None
    updater: _PluginModel
    segmenter: _PluginModel | None = None


class _FileModel(BaseModel):
    model_config = ConfigDict(extra="forbid")

    systems: list[_SystemModel] = Field(min_length=1)


@dataclass(frozen=True)
class ExtraSystem:
    """A system mapped beside Table IV's.

    Attributes:
        id: the records' row (``extra/mapping/<id>/...``).
        label: its name in the report.
        updater: the registered updater and its options.
        segmenter: the registered segmenter and its options, or None (geometry only).
        segmenter_is_network: whether the segmenter has a torch module (then it needs weights,
            or the oracle stands in for its labels).
    """

    id: str
    label: str
    updater: Component
    segmenter: Component | None = None
    segmenter_is_network: bool = False

    def as_dict(self) -> dict[str, Any]:
        return {"id": self.id, "label": self.label,
                "updater": {"name": self.updater.name, "options": self.updater.config},
                "segmenter": None if self.segmenter is None else
                {"name": self.segmenter.name, "options": self.segmenter.config}}


def _component(plugin: _PluginModel) -> Component:
    return Component(plugin.name, tuple(sorted(plugin.options.items())))


_PLAIN_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _one_line(text: str) -> str:
    """``text`` (a factory's message quoting the file's values) with line breaks escaped."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def _where(loc: tuple[Any, ...]) -> str:
    """``systems[0].updater.name``; a key that is not a plain word is quoted (``[' a\\n']``)."""
    out = ""
    for part in loc:
        if isinstance(part, int) or not _PLAIN_KEY.fullmatch(str(part)):
            out += f"[{part!r}]"
        else:
            out += f".{part}" if out else str(part)
    return out


def parse_systems(data: dict[str, Any], *, source: str,
                  taken: Set[str] = frozenset()) -> list[ExtraSystem]:
    """The systems of a parsed file ``data`` (``source`` names it in messages); ``taken`` are
    row ids already in use (Table IV's)."""
    try:
        model = _FileModel.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        more = len(exc.errors()) - 1
        message = _one_line(str(first["msg"]))
        raise EvsmapError(f"{source}: {_where(first['loc']) or 'the file'}: {message}"
                          + (f" (and {more} more)" if more else "")) from None
    from evsmap.registry import SEGMENTERS, UPDATERS

    systems: list[ExtraSystem] = []
    seen: set[str] = set()
    for n, s in enumerate(model.systems):
        where = f"{source}: systems[{n}] ({s.id!r})"
        if not ID.fullmatch(s.id):
            raise EvsmapError(f"{where}: an id is lower-case letters, digits, '-', '_' or '.'")
        if s.id in taken or s.id in seen:
            raise EvsmapError(f"{where}: the id is taken ("
                              + ("a Table IV row" if s.id in taken else "an earlier system")
                              + "); choose another")
        seen.add(s.id)
        updater = _component(s.updater)
        try:
            entry = UPDATERS.get(updater.name)
            if not entry.takes.resolution:
                raise EvsmapError(f"updater {updater.name!r} takes no resolution (the run maps "
                                  f"at Table IV's voxel size)")
            UPDATERS.create(updater.name, resolution=0.1, **updater.config)
            segmenter, network = None, False
            if s.segmenter is not None:
                segmenter = _component(s.segmenter)
                network = SEGMENTERS.create(segmenter.name, **segmenter.config).module \
                    is not None
        # an unknown name, or a factory refusing an option (its message may quote the file)
        except (EvsmapError, TypeError, ValueError, OverflowError) as exc:
            raise EvsmapError(f"{where}: {_one_line(str(exc))}") from None
        systems.append(ExtraSystem(id=s.id, label=s.label or s.id, updater=updater,
                                   segmenter=segmenter, segmenter_is_network=network))
    return systems


def load_systems(path: str | PathLike[str], *, taken: Set[str] = frozenset()
                 ) -> list[ExtraSystem]:
    """The systems of TOML file ``path`` (see the module notes)."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise EvsmapError(f"--systems {path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise EvsmapError(f"--systems {path}: cannot read ({exc})") from None
    except ValueError as exc:  # TOMLDecodeError, or an integer of more than 4300 digits
        raise EvsmapError(f"--systems {path}: not valid TOML ({exc})") from None
    except RecursionError:
        raise EvsmapError(f"--systems {path}: not valid TOML (nested too deeply)") from None
    return parse_systems(data, source=str(path), taken=taken)


def systems_from_records(items: list[dict[str, Any]], *, source: str) -> list[ExtraSystem]:
    """The systems a run stored in its ``run.json`` (``ExtraSystem.as_dict``), for
    ``--resume``."""
    return parse_systems({"systems": [{k: v for k, v in item.items() if v is not None}
                                      for item in items]}, source=source)
