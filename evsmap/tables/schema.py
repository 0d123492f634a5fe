"""The paper tables' public names, in one place (what other modules import).

The package is split by job:

* :mod:`evsmap.tables.records` - the records: :class:`PaperTable`, :class:`Column`,
  :class:`Cell`, :class:`System` (a :class:`SegmenterRef`: a model card or a segmenter name),
  :class:`Component`, :data:`QUANTITIES`;
* :mod:`evsmap.tables.models` - the file's shape as pydantic models, errors as one line;
* :mod:`evsmap.tables.cells` - the printed-cell grammar, printed text -> value in base units;
* :mod:`evsmap.tables.load` - :func:`load_tables`, :func:`load_file`, :func:`parse_tables`, and
  the tables' rules as data: :func:`table_ids`, :func:`table_numbers`, :func:`mapping_table`;
* :mod:`evsmap.tables.plan` - runner planning: :class:`CellSpec`, :func:`expand`,
  :func:`expand_all`.
"""

from evsmap.tables.load import (
    default_path,
    load_file,
    load_tables,
    mapping_table,
    mapping_table_id,
    parse_tables,
    table_ids,
    table_numbers,
)
from evsmap.tables.plan import CellSpec, expand, expand_all
from evsmap.tables.records import (
    BLANK,
    CHECK,
    KINDS,
    MARKS,
    QUANTITIES,
    SCHEMA_VERSION,
    TABLES_FILE,
    UNIT_SCALE,
    Cell,
    Claim,
    Column,
    Component,
    PaperTable,
    PaperTables,
    Quantity,
    SegmenterRef,
    System,
    TableSchemaError,
)

__all__ = ["BLANK", "CHECK", "KINDS", "MARKS", "QUANTITIES", "SCHEMA_VERSION", "TABLES_FILE",
           "UNIT_SCALE", "Cell", "CellSpec", "Claim", "Column", "Component", "PaperTable",
           "PaperTables", "Quantity", "SegmenterRef", "System", "TableSchemaError", "default_path",
           "expand", "expand_all", "load_file", "load_tables", "mapping_table",
           "mapping_table_id", "parse_tables", "table_ids", "table_numbers"]
