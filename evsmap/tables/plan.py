"""Runner planning: a paper table's implemented rows expanded into runnable cells.

:func:`expand` turns a :class:`~evsmap.tables.records.PaperTable` into :class:`CellSpec` s: what
one run measures (a system on one dataset or sequence at one resolution, a set of metrics), with
a stable ``key``, a ``config_key`` shared by the cells that measure the same thing, and the
requirements that may be missing (``needs``). A row's segmenter is resolved here, per cell: its
model card for the cell's dataset (:meth:`~evsmap.tables.records.SegmenterRef.resolve`), so
resolving loads the registries; :func:`~evsmap.tables.load.load_tables` itself does not.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

from evsmap.errors import UnknownNameError
from evsmap.tables.load import load_tables
from evsmap.tables.records import (
    KINDS,
    Cell,
    Column,
    Component,
    PaperTable,
    System,
    TableSchemaError,
)


@dataclass(frozen=True)
class CellSpec:
    """One runnable measurement: a system, its data, its resolution and the metrics it yields.

    Attributes:
        key: stable unique identifier
            ``table/row/kind[/datasets[:split]][@WxH][@Rm][#hardware][quantities]``, e.g.
            ``table1/feagnet-v2/accuracy/nyuv2:test[miou]`` (for resume and caching).
        config_key: the same without table and row: runs with equal ``config_key`` measure the
            same thing (FEAGNet-V2's NYUv2 mIoU in Tables I and III).
        table, row, label: where the cell comes from.
        kind: ``accuracy``, ``complexity``, ``speed`` or ``mapping``.
        segmenter, updater: what to build (options applied for the dataset).
        datasets: datasets or sequences (empty for complexity and speed).
        split: dataset split, if any.
        input_size: network input ``(height, width)``, if fixed by the column.
        resolution: map resolution, metres (mapping cells).
        hardware: the ``[hardware]`` id the paper measured on, if stated.
        metrics: the column ids this run fills.
        paper: the printed cells of those columns.
        fresh_process: a timing measurement: run it in a fresh process.
        requires: everything the run needs beyond evsmap itself (``dataset:X``,
            ``weights:SEGMENTER@DATASET``, ``hardware:X``).
        needs: the part of ``requires`` not in the ``available`` set given to :func:`expand`.
    """

    key: str
    config_key: str
    table: str
    row: str
    label: str
    kind: str
    segmenter: Component | None
    updater: Component | None
    datasets: tuple[str, ...]
    split: str | None
    input_size: tuple[int, int] | None
    resolution: float | None
    hardware: str | None
    metrics: tuple[str, ...]
    paper: tuple[Cell, ...] = field(repr=False)
    fresh_process: bool
    requires: tuple[str, ...]
    needs: tuple[str, ...]

    @property
    def printed_size(self) -> str | None:
        """``WxH`` input size or ``R m`` voxel size, as the paper prints it."""
        if self.input_size is not None:
            return f"{self.input_size[1]}x{self.input_size[0]}"
        if self.resolution is not None:
            return f"{self.resolution:g} m"
        return None

    @property
    def runnable(self) -> bool:
        """Nothing required is missing."""
        return not self.needs


def _requirements(kind: str, segmenter: Component | None, datasets: tuple[str, ...],
                  hardware: str | None, weights_dataset: str | None) -> tuple[str, ...]:
    req = []
    if kind in ("accuracy", "mapping"):
        req += [f"dataset:{d}" for d in datasets]
        if segmenter is not None and segmenter.name != "oracle":
            req.append(f"weights:{segmenter.spec}@{weights_dataset}")
    if hardware is not None:
        req.append(f"hardware:{hardware}")
    return tuple(sorted(set(req)))


def _groups(table: PaperTable, system: System) -> list[tuple[list[Column], str | None]]:
    """A row's measured columns grouped into runs, ordered by :data:`KINDS`, then by first
    column. Columns of one kind go together when they share datasets, split, input and voxel
    size, hardware and timing; a complexity column without an input size (parameters) joins
    the row's first complexity run."""
    groups: dict[tuple, list[Column]] = {}
    loose: list[Column] = []
    for col in table.columns:
        if col.kind == "flag" or (col.kind != "mapping" and system.network is None):
            continue  # flags are settings; an updater-only system has no network to score
        hw = table.cell(system.id, col.id).hardware
        if col.kind == "complexity" and col.input_size is None:
            loose.append(col)
            continue
        key = (col.kind, col.datasets, col.split, col.input_size, col.resolution, hw,
               col.timing)
        groups.setdefault(key, []).append(col)
    if loose:
        target = next((k for k in groups if k[0] == "complexity"), None)
        if target is None:
            groups[("complexity", (), None, None, None, None, False)] = loose
        else:
            groups[target] = sorted(loose + groups[target], key=table.columns.index)
    ordered = sorted(groups.items(), key=lambda kv: KINDS.index(kv[0][0]))  # stable sort
    return [(cols, key[5]) for key, cols in ordered]


def _segmenter(table: PaperTable, system: System, dataset: str | None) -> Component | None:
    try:
        return system.segmenter_for(dataset)
    except UnknownNameError as exc:
        raise TableSchemaError(f"table {table.id}, row {system.id!r}: {exc}") from None


def expand(table: PaperTable, *, available: Iterable[str] | None = None,
           mapping_weights: str = "nyuv2") -> list[CellSpec]:
    """The runnable cells of ``table``'s implemented rows, in row order and, within a row, by
    kind (accuracy, complexity, speed, mapping) and then column order.

    A row's columns of one kind that share datasets, split, input and voxel size and hardware
    make one cell (Table I's params and FLOPs are one complexity run). Paper-only rows
    (``implemented = false``) are skipped; flags are not measured.

    Args:
        available: requirement strings that are satisfied (``"dataset:nyuv2"``,
            ``"weights:feagnet-v2@nyuv2"``, ``"hardware:jetson-tensorrt"``); what a cell
            requires beyond them is its ``needs``. ``None``: nothing is assumed available.
        mapping_weights: the dataset the segmenters of mapping systems are trained on (the
            paper does not say; NYUv2's 40 classes).
    """
    have = frozenset(available or ())
    out: list[CellSpec] = []
    for system in table.rows:
        if not system.implemented:
            continue
        for cols, hw in _groups(table, system):
            first = cols[0]
            kind, datasets, split = first.kind, first.datasets, first.split
            size = next((c.input_size for c in cols if c.input_size is not None), None)
            voxel = first.resolution
            timing = first.timing
            weights_ds: str | None
            if kind == "mapping":
                weights_ds = mapping_weights
            else:
                weights_ds = datasets[0] if kind == "accuracy" else None
            segmenter = _segmenter(table, system, weights_ds)
            requires = _requirements(kind, segmenter, datasets, hw, weights_ds)
            what = kind
            if datasets:
                what += "/" + "+".join(datasets) + (f":{split}" if split else "")
            if size is not None:
                what += f"@{size[1]}x{size[0]}"
            if voxel is not None:
                what += f"@{voxel:g}m"
            if hw is not None:
                what += f"#{hw}"
            what += "[" + ",".join(c.quantity for c in cols) + "]"
            systems = "+".join(c.spec for c in (segmenter, system.updater) if c is not None)
            out.append(CellSpec(
                key=f"{table.id}/{system.id}/{what}", config_key=f"{systems}/{what}",
                table=table.id, row=system.id, label=system.label, kind=kind,
                segmenter=segmenter, updater=system.updater, datasets=datasets, split=split,
                input_size=size, resolution=voxel, hardware=hw,
                metrics=tuple(c.id for c in cols),
                paper=tuple(table.cell(system.id, c.id) for c in cols),
                fresh_process=timing, requires=requires,
                needs=tuple(r for r in requires if r not in have)))
    keys = [c.key for c in out]
    if len(set(keys)) != len(keys):  # pragma: no cover - guarded by the tests
        raise TableSchemaError(f"table {table.id}: expansion produced duplicate keys")
    return out


def expand_all(tables: Mapping[str, PaperTable] | None = None, *,
               available: Iterable[str] | None = None) -> list[CellSpec]:
    """:func:`expand` over every table (all of :func:`load_tables` by default), in id order."""
    tables = load_tables() if tables is None else tables
    have = None if available is None else list(available)
    return [spec for tid in sorted(tables) for spec in expand(tables[tid], available=have)]
