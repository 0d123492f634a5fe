"""Where evsmap finds shared data by default."""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent


def default_data_root() -> Path | None:
    """``$EVSMAP_DATA_ROOT``, else ``../shared/data`` beside the checkout, else ``None``."""
    env = os.environ.get("EVSMAP_DATA_ROOT")
    if env:
        return Path(env)
    for candidate in (Path.cwd().parent / "shared" / "data", REPO_ROOT.parent / "shared" / "data"):
        if candidate.is_dir():
            return candidate
    return None
