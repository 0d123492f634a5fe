"""Where the latest study's report is: ``explore/latest.json`` in evsmap's cache, written when a
study writes its ``index.md``, read by ``evsmap reproduce`` to link it from Table IV's section."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

LATEST_FILE = "latest.json"


def _path() -> Path:
    from evsmap.cache import cache_dir

    return cache_dir("explore") / LATEST_FILE


def record_latest(index: str | os.PathLike[str], summary: str) -> None:
    """Remember ``index`` (a study's ``index.md``) and its one-line answer as the latest."""
    from evsmap.fileio import atomic_write_text

    path = _path()
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps({"index": str(Path(index).resolve()),
                                        "summary": summary, "written": time.time()}))


def latest_study() -> dict[str, Any] | None:
    """``{"index", "summary", "written"}`` of the latest study whose ``index.md`` still
    exists, else ``None``."""
    try:
        data = json.loads(_path().read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or not Path(str(data.get("index", ""))).is_file():
        return None
    return data
