"""The shape of ``paper_tables.toml`` as pydantic models, and its errors as one line.

:class:`FileModel` is the whole file: ``schema_version``, ``source``, ``[hardware.<id>]``
(:class:`HardwareModel`), ``[datasets.<id>]`` (:class:`DatasetModel`) and ``[tables.<id>]``
(:class:`TableModel`: ``columns`` (:class:`ColumnModel`), ``rows`` (:class:`RowModel` with a
``segmenter`` (:class:`SegmenterModel`: a model ``card`` or a registered ``name``), an
``updater`` (:class:`ComponentModel`) and its ``cells`` (:class:`CellModel`: a printed string or
an inline table ``{printed, bold, hardware, note}``)). Every model forbids unknown keys and takes
TOML's own types (no "3" for 3). The validators check what ties the objects together: a unit
that fits its quantity, paired ``*_source`` keys, unique ids, one cell per column, each printed
as its column needs (the grammar of :mod:`evsmap.tables.cells`: "92.0", "7.9†", "-", "√" or ""
in flag columns), hardware only on timing columns, and declared datasets and hardware.

:func:`validate` returns the :class:`FileModel` or raises
:class:`~evsmap.tables.records.TableSchemaError` whose message is one line: the file, the place
in the words of the tables (``table table1, row '3dgnn-r101', column 'fps'``) and what is wrong.
"""

from __future__ import annotations

import re
import types
from collections.abc import Mapping, Sequence
from typing import Annotated, Any, Literal, Union, get_args, get_origin

from pydantic import (
    AliasChoices,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)
from pydantic_core import PydanticCustomError

from evsmap.tables.cells import make_cell
from evsmap.tables.records import (
    BLANK,
    QUANTITIES,
    SCHEMA_VERSION,
    Claim,
    Column,
    TableSchemaError,
)

_ID_PATTERN = r"^[a-z0-9][a-z0-9_.+-]*$"

OLD_COLUMN_KEYS: dict[str, tuple[str, ...]] = {
    "resolution": ("voxel_size",), "resolution_source": ("voxel_size_source",)}
"""A column's key -> the names it had before (a table file written then still loads): the map's
leaf size was ``voxel_size`` in the tables and ``resolution`` everywhere else until issue 55."""

Text = Annotated[str, Field(strict=True)]
Flag = Annotated[bool, Field(strict=True)]
Year = Annotated[int, Field(strict=True)]
Pixels = Annotated[int, Field(strict=True, gt=0)]
Metres = Annotated[float, Field(strict=True, gt=0)]
Source = Literal["paper", "assumed"]
Role = Literal["networks", "ablation", "mapping"]


def _error(message: str, *loc: str | int) -> PydanticCustomError:
    """A validation error whose message is ``message`` as it is, about the object at ``loc``
    inside the one being validated (a table's validator names a row's cell)."""
    return PydanticCustomError("evsmap", "{message}", {"message": message, "loc": loc})


def _check_id(value: str) -> str:
    if not re.match(_ID_PATTERN, value):
        raise _error(f"ids are lower case letters, digits and _.+- (got {value!r})")
    return value


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class HardwareModel(_Model):
    """``[hardware.<id>]``: where a speed was measured."""

    description: Text
    note: Text = ""


class DatasetModel(_Model):
    """``[datasets.<id>]``: a dataset or sequence the columns refer to."""

    description: Text
    inferred: Flag = False


class ColumnModel(_Model):
    """``[[tables.<id>.columns]]``: one printed metric or flag column."""

    id: Text
    header: Text
    quantity: Text
    unit: Text = ""
    dataset: list[Text] = []
    split: Text | None = None
    input_size: tuple[Pixels, Pixels] | None = None
    input_size_source: Source | None = None
    resolution: Metres | None = Field(None, validation_alias=AliasChoices(
        "resolution", *OLD_COLUMN_KEYS["resolution"]))
    resolution_source: Source | None = Field(None, validation_alias=AliasChoices(
        "resolution_source", *OLD_COLUMN_KEYS["resolution_source"]))
    note: Text = ""

    @field_validator("id")
    @classmethod
    def _id(cls, value: str) -> str:
        return _check_id(value)

    @field_validator("dataset", mode="before")
    @classmethod
    def _one_or_many(cls, value: Any) -> Any:
        return [value] if isinstance(value, str) else value

    @field_validator("input_size", mode="before")
    @classmethod
    def _height_width(cls, value: Any) -> Any:
        if value is not None and not (isinstance(value, list) and len(value) == 2):
            raise _error(f"expected [height, width], got {value!r}")
        return value

    @field_validator("quantity")
    @classmethod
    def _known_quantity(cls, value: str) -> str:
        if value not in QUANTITIES:
            raise _error(f"unknown quantity {value!r} (known: {', '.join(QUANTITIES)})")
        return value

    def record(self) -> Column:
        """The :class:`~evsmap.tables.records.Column`."""
        return Column(id=self.id, header=self.header, quantity=self.quantity, unit=self.unit,
                      datasets=tuple(self.dataset), split=self.split, input_size=self.input_size,
                      input_size_source=self.input_size_source,
                      resolution=None if self.resolution is None else float(self.resolution),
                      resolution_source=self.resolution_source, note=self.note)

    @model_validator(mode="after")
    def _consistent(self) -> ColumnModel:
        q = QUANTITIES[self.quantity]
        if self.unit not in q.units:
            raise _error(f"unit {self.unit!r} does not fit quantity {self.quantity!r} "
                         f"(allowed: {', '.join(map(repr, q.units))})")
        if q.kind in ("accuracy", "mapping") and not self.dataset:
            raise _error(f"a {self.quantity} column needs a dataset")
        for key, value in (("input_size", self.input_size), ("resolution", self.resolution)):
            if (value is None) != (getattr(self, f"{key}_source") is None):
                raise _error(f"give {key}_source exactly when {key} is given")
        return self


class ComponentModel(_Model):
    """A registered plug-in (``updater = { name = ..., options = {...} }``)."""

    name: Text
    options: dict[str, Any] = {}


class SegmenterModel(_Model):
    """A row's network: ``{ card = "feagnet-v1" }`` (a model card, resolved per dataset) or
    ``{ name = "oracle" }`` (a registered segmenter), with ``options`` on top."""

    card: Text | None = None
    name: Text | None = None
    options: dict[str, Any] = {}

    @model_validator(mode="after")
    def _card_or_name(self) -> SegmenterModel:
        if (self.card is None) == (self.name is None):
            raise _error("give either 'card' (a model card) or 'name' (a registered segmenter)")
        return self


class CellModel(_Model):
    """A printed cell: ``"47.6"`` or ``{ printed = "54.8", bold = true, hardware = "..." }``."""

    printed: Text
    bold: Flag = False
    hardware: Text | None = None
    note: Text = ""

    @model_validator(mode="before")
    @classmethod
    def _printed_string(cls, value: Any) -> Any:
        if isinstance(value, str):
            return {"printed": value}
        if not isinstance(value, Mapping):
            raise _error(f"a cell is a printed string or an inline table, got {value!r}")
        return value


class RowModel(_Model):
    """``[[tables.<id>.rows]]``: one system of the paper and its cells."""

    id: Text
    label: Text
    implemented: Flag
    segmenter: SegmenterModel | None = None
    updater: ComponentModel | None = None
    inputs: Text | None = None
    year: Year | None = None
    ablation: Text | None = None
    note: Text = ""
    cells: dict[str, CellModel] = {}

    @field_validator("id")
    @classmethod
    def _id(cls, value: str) -> str:
        return _check_id(value)

    @model_validator(mode="after")
    def _runnable(self) -> RowModel:
        if self.implemented and self.segmenter is None and self.updater is None:
            raise _error("an implemented row needs a segmenter or an updater")
        return self


class ClaimModel(_Model):
    """``[[tables.<id>.claims]]``: a comparative claim of the paper about ``row``'s ``column``
    against the table's baseline row."""

    text: Text
    row: Text
    column: Text
    mode: Literal["higher", "lower", "match"]

    def record(self, table: str, base: str) -> Claim:
        """The :class:`~evsmap.tables.records.Claim` of table ``table`` against ``base``."""
        return Claim(self.text, table, self.row, base, self.column, self.mode)


class TableModel(_Model):
    """``[tables.<id>]``: one printed table, and what it is (``role``, ``baseline``, ...: see
    :class:`~evsmap.tables.records.PaperTable`)."""

    number: Text
    title: Text
    role: Role = "networks"
    baseline: Text | None = None
    own_method: Flag = False
    trained_beside: Flag = False
    caption: Text = ""
    footnotes: dict[str, Text] = {}
    note: Text = ""
    claims: list[ClaimModel] = []
    columns: list[ColumnModel] = Field(min_length=1)
    rows: list[RowModel] = Field(min_length=1)

    @model_validator(mode="after")
    def _cells_fit_columns(self) -> TableModel:
        """Unique ids; every row has one cell per column, each printed as its column needs."""
        for what, items in (("column", self.columns), ("row", self.rows)):
            seen: set[str] = set()
            for item in items:
                if item.id in seen:
                    raise _error(f"{what} id {item.id!r} appears twice")
                seen.add(item.id)
        columns = {c.id: c.record() for c in self.columns}
        for i, row in enumerate(self.rows):
            for cid in row.cells:
                if cid not in columns:
                    raise _error(f"no such column (columns: {', '.join(columns)})",
                                 "rows", i, "cells", cid)
            for cid, column in columns.items():
                cell = row.cells.get(cid)
                if cell is None:
                    raise _error(f"cell missing (write \"{BLANK}\" for a cell the paper leaves "
                                 "blank)", "rows", i, "cells", cid)
                if cell.hardware is not None and not column.timing:
                    raise _error("hardware applies to timing columns only", "rows", i, "cells",
                                 cid)
                try:
                    make_cell("", row.id, column, cell.printed)
                except ValueError as exc:
                    raise _error(str(exc), "rows", i, "cells", cid) from None
        return self

    @model_validator(mode="after")
    def _rules_name_rows(self) -> TableModel:
        """The baseline and the claims name this table's rows and columns."""
        rows = {r.id for r in self.rows}
        columns = {c.id for c in self.columns}
        if self.baseline is not None and self.baseline not in rows:
            raise _error(f"baseline {self.baseline!r} is not a row of the table")
        for i, claim in enumerate(self.claims):
            if self.baseline is None:
                raise _error("a claim needs the table's baseline", "claims", i)
            if claim.row not in rows:
                raise _error(f"no such row {claim.row!r}", "claims", i, "row")
            if claim.column not in columns:
                raise _error(f"no such column {claim.column!r}", "claims", i, "column")
        return self


class FileModel(_Model):
    """The whole file."""

    schema_version: Any = Field(default=None, validate_default=True)
    source: Text = ""
    hardware: dict[str, HardwareModel] = {}
    datasets: dict[str, DatasetModel] = {}
    tables: dict[str, TableModel] = Field(min_length=1)

    @field_validator("schema_version")
    @classmethod
    def _version(cls, value: Any) -> Any:
        if value != SCHEMA_VERSION or isinstance(value, bool):
            raise _error(f"schema_version must be {SCHEMA_VERSION}, got {value!r}")
        return value

    @model_validator(mode="after")
    def _one_mapping_table(self) -> FileModel:
        """At most one table's rows are the mapping systems."""
        mapping = [tid for tid, t in self.tables.items() if t.role == "mapping"]
        if len(mapping) > 1:
            raise _error(f"only one table may have role 'mapping' (got {', '.join(mapping)})",
                         "tables", mapping[1], "role")
        return self

    @model_validator(mode="after")
    def _declared(self) -> FileModel:
        """The columns' datasets and the cells' hardware are declared."""
        for tid, table in self.tables.items():
            for j, column in enumerate(table.columns):
                for d in column.dataset:
                    if d not in self.datasets:
                        raise _error(f"unknown dataset {d!r} (declared: "
                                     f"{', '.join(sorted(self.datasets))})", "tables", tid,
                                     "columns", j)
            for i, row in enumerate(table.rows):
                for cid, cell in row.cells.items():
                    if cell.hardware is not None and cell.hardware not in self.hardware:
                        raise _error(f"unknown hardware {cell.hardware!r} (declared: "
                                     f"{', '.join(sorted(self.hardware)) or 'none'})",
                                     "tables", tid, "rows", i, "cells", cid)
        return self


def validate(data: Mapping[str, Any], *, source: str) -> FileModel:
    """``data`` (parsed TOML) as a :class:`FileModel`.

    Raises:
        TableSchemaError: one line: ``source``, the place and the first thing wrong.
    """
    try:
        return FileModel.model_validate(data)
    except ValidationError as exc:
        raise TableSchemaError(describe(exc, data, source=source)) from None


# ------------------------------------------------------------------------------- messages
def describe(exc: ValidationError, data: Mapping[str, Any], *, source: str) -> str:
    """The first error of ``exc`` as ``source: place: message`` (unknown keys of one object
    together)."""
    errors = exc.errors()
    first = errors[0]
    loc = tuple(first["loc"]) + tuple((first.get("ctx") or {}).get("loc", ()))
    kind = first["type"]
    if kind == "extra_forbidden":
        loc = loc[:-1]
        keys = [e["loc"][-1] for e in errors
                if e["type"] == "extra_forbidden" and tuple(e["loc"][:-1]) == loc]
        model = _model_at(loc)
        allowed = f" (allowed: {', '.join(sorted(model.model_fields))})" if model else ""
        message = f"unknown key(s) {', '.join(map(repr, keys))}{allowed}"
    elif kind == "missing":
        what = f"item {loc[-1]}" if isinstance(loc[-1], int) else repr(loc[-1])
        loc, message = loc[:-1], f"missing {what}"
    else:
        message = str(first["msg"]).removeprefix("Value error, ")
        got = repr(first.get("input"))
        if kind not in ("evsmap", "value_error") and len(got) <= 60:
            message += f", got {got}"
    place, rest = _place(loc, data)
    if rest and not message.startswith(f"{rest[-1]} "):
        message = f"{'.'.join(map(str, rest))}: {message}"
    more = len(errors) - 1
    tail = f" (and {more} more error{'s' if more > 1 else ''})" if more > 0 and \
        kind != "extra_forbidden" else ""
    return f"{source}: {place + ': ' if place else ''}{message}{tail}"


def _place(loc: tuple, data: Mapping[str, Any]) -> tuple[str, tuple]:
    """``loc`` in the tables' words and the rest of it (field names inside that place)."""
    if len(loc) >= 2 and loc[0] in ("hardware", "datasets"):
        return f"{'hardware' if loc[0] == 'hardware' else 'dataset'} {loc[1]!r}", loc[2:]
    if len(loc) < 2 or loc[0] != "tables":
        return "", loc
    words, rest = [f"table {loc[1]}"], loc[2:]
    if len(rest) >= 2 and rest[0] in ("columns", "rows") and isinstance(rest[1], int):
        what = rest[0][:-1]
        item = _item(data, loc[:4])
        ident = item.get("id") if isinstance(item, Mapping) else None
        words.append(f"{what} {ident!r}" if isinstance(ident, str) else f"{what} #{rest[1] + 1}")
        rest = rest[2:]
        if what == "row" and len(rest) >= 2 and rest[0] == "cells":
            words.append(f"column {rest[1]!r}")
            rest = rest[2:]
            if rest[:1] == ("printed",):
                rest = rest[1:]
    return ", ".join(words), rest


def _item(data: Any, loc: Sequence) -> Any:
    for part in loc:
        try:
            data = data[part]
        except (KeyError, IndexError, TypeError):
            return None
    return data


def _model_at(loc: tuple) -> type[BaseModel] | None:
    """The model that validates the object at ``loc``."""
    node: Any = FileModel
    for part in loc:
        node = _optional(node)
        if isinstance(node, type) and issubclass(node, BaseModel):
            field = node.model_fields.get(str(part))
            if field is None:
                return None
            node = field.annotation
        else:
            args = get_args(node)
            if get_origin(node) not in (list, dict) or not args:
                return None
            node = args[-1]
    node = _optional(node)
    return node if isinstance(node, type) and issubclass(node, BaseModel) else None


def _optional(hint: Any) -> Any:
    if get_origin(hint) in (Union, types.UnionType):
        args = [a for a in get_args(hint) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return hint
