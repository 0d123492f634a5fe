"""The paper's Tables I-IV as data (``paper_tables.toml``) and their expansion into runnable
cells; see :mod:`evsmap.tables.schema`."""

from evsmap.tables.schema import (
    QUANTITIES,
    Cell,
    CellSpec,
    Column,
    Component,
    PaperTable,
    PaperTables,
    SegmenterRef,
    System,
    TableSchemaError,
    expand,
    expand_all,
    load_file,
    load_tables,
    parse_tables,
)

__all__ = ["QUANTITIES", "Cell", "CellSpec", "Column", "Component", "PaperTable", "PaperTables",
           "SegmenterRef", "System", "TableSchemaError", "expand", "expand_all", "load_file",
           "load_tables", "parse_tables"]
