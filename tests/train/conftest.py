"""Shared pieces of the training tests: one intra-op thread, a tiny labelled dataset whose class
is a function of the colour (:mod:`train_fixtures`), a FEAGNet-V1 at 128x192 and a small recipe.
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from train_fixtures import CLASSES, SIZE, TINY, colour_frames

from evsmap.registry import SEGMENTERS


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    """One intra-op thread: on a busy 2-core runner OpenMP threads spin-waiting for each other
    make small forward passes many times slower."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="session")
def colour_data(tmp_path_factory) -> Path:
    """8 colour frames at 128x192 in the TUM layout (a folder any evsmap command reads; the
    reader has no splits, so training validates on the training frames)."""
    from evsmap.readers.tum import write_tum

    out = tmp_path_factory.mktemp("train-data") / "colours"
    write_tum(colour_frames(8), out)
    return out


@pytest.fixture(scope="session")
def tiny_model() -> str:
    """``feagnet-v1-test``: FEAGNet-V1 with 4 classes at input size 128x192 (registered for the
    session, in this process only)."""

    def factory(*, num_classes: int = CLASSES, weights: str | None = None,
                backend: str = "torch", multiscale: bool = True):
        return SEGMENTERS.create("feagnet-v1", num_classes=num_classes, weights=weights,
                                 backend=backend, input_size=SIZE, multiscale=multiscale)

    SEGMENTERS.add(TINY, factory, description="FEAGNet-V1, 4 classes, 128x192 (tests)")
    yield TINY
    SEGMENTERS.unregister(TINY)


@pytest.fixture(scope="session")
def tiny_recipe(tmp_path_factory) -> Path:
    """The paper's recipe with batch 4, lr 0.01, no data-loading processes, 2 epochs."""
    path = tmp_path_factory.mktemp("recipes") / "tiny.toml"
    path.write_text('base = "paper"\nname = "tiny"\nepochs = 2\nbatch_size = 4\nlr = 0.01\n'
                    'workers = 0\n')
    return path
