"""Helpers for test suites (ours and plug-in authors'): a missing piece skips locally, fails in CI.

A test that needs a real sample, an optional library or a compiled kernel calls one of these
instead of ``pytest.skip``: on a developer's machine it skips with the exact command that
provides the piece; with ``CI=true`` in the environment the same call fails the test, so a CI
run can never go green while pieces are silently missing.
"""

from __future__ import annotations

import importlib
import os
from pathlib import Path
from types import ModuleType

from evsmap.paths import DATA_ROOT_ENV, default_data_root


def in_ci() -> bool:
    """Whether ``$CI`` is set to a true value (``true``, ``1``, ``yes``)."""
    return os.environ.get("CI", "").strip().lower() in ("1", "true", "yes")


def missing(reason: str) -> None:
    """Skip the calling test with ``reason``, or fail it when running in CI."""
    import pytest

    if in_ci():
        pytest.fail(f"{reason} [CI=true: a missing piece fails instead of skipping]",
                    pytrace=False)
    pytest.skip(reason)


def require_module(name: str, hint: str | None = None) -> ModuleType:
    """Import ``name`` or call :func:`missing` (``hint``: how to install it)."""
    try:
        return importlib.import_module(name)
    except ImportError as exc:
        how = hint or f"pip install -c constraints.txt -e '.[test]' (provides {name})"
        missing(f"{name} cannot be imported ({exc}); {how}")
        raise  # pragma: no cover  (missing() always raises)


def require_sample(name: str) -> Path:
    """The path of the real sample ``name`` (see :data:`evsmap.samples.SAMPLES`) in the data root.

    Skips (fails in CI) naming the command that fetches it when it is absent.
    """
    from evsmap.samples import SAMPLES

    sample = SAMPLES[name]
    root = default_data_root()
    path = root / sample.folder
    if not path.exists():
        missing(f"sample {name!r} not found at {path} (data root: ${DATA_ROOT_ENV}, "
                f"../shared/data or ~/.cache/evsmap/data); fetch it with "
                f"`evsmap datasets fetch {name}`")
    return path
