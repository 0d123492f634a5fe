"""The keys records used before the rates of a mapping run had one name each.

Every record of a mapping run (``evsmap map --json``, the runner's ``extra/mapping/...`` records,
the report's tables and figures, the benchmarks) names its rates ``update_hz``,
``segment_update_hz`` and ``wall_hz`` (:class:`evsmap.measure.mapping.MappingRecord`; the table
of quantities is in docs/measurement.md, "Quantities"). A stored run from before
is read through :data:`OLD_KEYS`, so ``evsmap report`` rebuilds it with the same tables.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Final

from evsmap import fileio

OLD_KEYS: Final[Mapping[str, str]] = {
    "hz_median": "update_hz",
    "hz_segment_update": "segment_update_hz",
    "hz_end_to_end": "wall_hz",
    "end_to_end_hz": "segment_update_hz",
}
"""Old key -> key, for records written before the rates had one name each: ``evsmap map``'s
``hz_median``, ``hz_segment_update`` and ``hz_end_to_end`` (frames / wall second), and the
runner's ``end_to_end_hz`` (which was the segmentation + update rate, not the wall rate).
:func:`renamed_keys` applies it to a record's ``values`` and ``details`` where a stored
record is read (:meth:`evsmap.runner.records.CellRecord.from_json`)."""


def renamed_keys(data: Mapping[str, Any]) -> dict[str, Any]:
    """``data`` with each key of :data:`OLD_KEYS` renamed
    (:func:`evsmap.fileio.renamed_keys`: a key already under its new name wins, order kept)."""
    return fileio.renamed_keys(data, OLD_KEYS)
