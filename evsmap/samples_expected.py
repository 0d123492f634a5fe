"""The expected check values of the samples (see :mod:`evsmap.samples`), by sample and relative
path: the data file ``samples_expected.json`` beside this module (package data).

``python -m evsmap.samples expected DATA_ROOT`` writes it from the real sample files of the
shared data root (:func:`write_expected`); it is never edited by hand. A value is a hex digest
(``sha256``, ``pixels``) or a tuple of numbers (``mean-rgb-2x2``, ``depth-stats``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from functools import cache
from pathlib import Path

DATA_FILE = Path(__file__).with_name("samples_expected.json")
FORMAT = "evsmap-samples-expected"
GENERATOR = "python -m evsmap.samples expected DATA_ROOT"

Value = str | tuple[float, ...]


@cache
def load_expected(path: Path = DATA_FILE) -> dict[str, dict[str, Value]]:
    """The expected values by sample name and relative path (lists read back as tuples)."""
    record = json.loads(Path(path).read_text(encoding="utf-8"))
    if not isinstance(record, dict) or record.get("format") != FORMAT:
        raise ValueError(f"{path}: not a {FORMAT} file")
    return {name: {rel: value if isinstance(value, str) else tuple(value)
                   for rel, value in files.items()}
            for name, files in record["samples"].items()}


def expected_for(name: str) -> Mapping[str, Value] | None:
    """The expected values of sample ``name``; ``None`` when the file has none."""
    return load_expected().get(name)


def write_expected(values: Mapping[str, Mapping[str, Value]], path: Path = DATA_FILE) -> None:
    """Write ``values`` (by sample, then relative path) as the data file: one file a line."""
    samples = []
    for name, files in values.items():
        rows = ",\n".join(f"    {json.dumps(rel)}: {json.dumps(value)}"
                          for rel, value in files.items())
        samples.append(f"  {json.dumps(name)}: {{\n{rows}\n  }}")
    head = f'{{"format": {json.dumps(FORMAT)}, "generated_by": {json.dumps(GENERATOR)},\n'
    Path(path).write_text(head + ' "samples": {\n' + ",\n".join(samples) + "\n}}\n",
                          encoding="utf-8")
