"""Where evsmap finds its data and caches by default.

The data root (``$EVSMAP_DATA_ROOT``, else ``../shared/data`` beside the checkout when present,
else ``~/.cache/evsmap/data``) is where the real sample sequences live - the ones the tests and
``evsmap reproduce`` use - and where ``evsmap datasets fetch`` puts them.
"""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
DATA_ROOT_ENV = "EVSMAP_DATA_ROOT"


def user_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/evsmap`` (``~/.cache/evsmap`` when unset)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "evsmap"


def shared_data_dir() -> Path | None:
    """``../shared/data`` beside the working directory or the checkout, when it exists."""
    for candidate in (Path.cwd().parent / "shared" / "data", REPO_ROOT.parent / "shared" / "data"):
        if candidate.is_dir():
            return candidate
    return None


def default_data_root() -> Path:
    """``$EVSMAP_DATA_ROOT``, else ``../shared/data`` when present, else ``~/.cache/evsmap/data``.

    The folder may not exist yet (nothing fetched): callers check what they need inside it.
    """
    env = os.environ.get(DATA_ROOT_ENV)
    if env:
        return Path(env).expanduser()
    return shared_data_dir() or user_cache_dir() / "data"
