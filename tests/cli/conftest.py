"""The tiny gated network of the int8 tests, registered for a command-line test
(``tests/cli/test_int8_cli.py``, ``tests/cli/test_device_cli.py``)."""

from __future__ import annotations

import pytest

import evsmap.measure.speed as speed_module
from evsmap.registry import SEGMENTERS
from tests.segmenters.int8_net import NAME, tiny_segmenter


@pytest.fixture
def tiny(monkeypatch, tmp_path):
    """The tiny network registered as ``NAME``, a cache of the test's own and a small roofline
    matmul (a fast test)."""
    SEGMENTERS.add(NAME, tiny_segmenter)
    monkeypatch.setenv("EVSMAP_CACHE_DIR", str(tmp_path / "cache"))
    real = speed_module.roofline_gmacs
    monkeypatch.setattr(speed_module, "roofline_gmacs", lambda size=0, **kw: real(64, **kw))
    yield NAME
    SEGMENTERS.unregister(NAME)
