"""The keys records used before the rates of a mapping run (and its leaf size) had one name each.

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
    "voxel_size": "resolution",
}
"""Old key -> key, for records written before the rates had one name each: ``evsmap map``'s
``hz_median``, ``hz_segment_update`` and ``hz_end_to_end`` (frames / wall second), and the
runner's ``end_to_end_hz`` (which was the segmentation + update rate, not the wall rate); and
the map's leaf size, ``voxel_size`` in the runner's records until issue 55 and ``resolution``
everywhere else. :func:`renamed_keys` applies it to a record's ``inputs``, ``values`` and
``details`` where a stored record is read (:meth:`evsmap.runner.records.CellRecord.from_json`)."""


def older_size_readings(values: Mapping[str, Any], inputs: Mapping[str, Any],
                        details: Mapping[str, Any]) -> dict[str, Any]:
    """A mapping record's ``values`` with the size readings as named since 2026-11-28, for a
    record written before: its ``map_bytes`` was then the ``published`` file, which for
    ``multiclass-bayes`` on SSMI's generator was SSMI's ``octomap_full`` message (36 B a node)
    and not the file SSMI saves (its colour-only ``ColorOcTree``). So ``map_bytes_message`` is
    that size for every system, and such a record's saved file is its ``map_bytes_colour``.
    A record that has ``map_bytes_message`` is returned as it is."""
    out = dict(values)
    if "map_bytes" not in values or "map_bytes_message" in values:
        return out
    out["map_bytes_message"] = values["map_bytes"]
    front_end = details.get("front_end")
    generator = isinstance(front_end, Mapping) and front_end.get("name") == "generator"
    if (generator and str(inputs.get("updater", "")).startswith("multiclass-bayes")
            and values.get("map_bytes_colour") is not None):
        out["map_bytes"] = values["map_bytes_colour"]
    return out


def renamed_keys(data: Mapping[str, Any]) -> dict[str, Any]:
    """``data`` with each key of :data:`OLD_KEYS` renamed
    (:func:`evsmap.fileio.renamed_keys`: a key already under its new name wins, order kept)."""
    return fileio.renamed_keys(data, OLD_KEYS)
