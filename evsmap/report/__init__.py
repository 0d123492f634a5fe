"""The report layer: the paper's tables with the measured values beside the printed ones, the
measurements beyond the paper, figures and an index, built from a run folder's stored records
(:func:`build_report`; ``evsmap report DIR``)."""

from evsmap.report.build import build_report, read_records, read_run
from evsmap.report.tables import (
    FRAME_COLUMNS,
    extra_frame,
    extra_markdown,
    format_number,
    table_frame,
    table_markdown,
)

__all__ = ["FRAME_COLUMNS", "build_report", "extra_frame", "extra_markdown", "format_number",
           "read_records", "read_run", "table_frame", "table_markdown"]
