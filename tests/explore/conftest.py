"""A small space and sequence for the study tests: two coarse resolutions, three update options,
a few frames of the synthetic room at 64x48 (a trial maps in well under a second)."""

from __future__ import annotations

from pathlib import Path

import pytest

from evsmap.explore.bench import Inputs

SMALL_SPACE = """
updater = "multiclass-bayes"
baseline = "tesamap"
reference = "octomap-cpp"

[sampler]
name = "tpe"
seed = 3
startup_trials = 2

[[objectives]]
name = "map_size"

[[objectives]]
name = "scene_miou"

[[parameters]]
name = "resolution"
target = "shared"
choices = [0.1, 0.2]
default = 0.1

[[parameters]]
name = "raycast_range"
target = "shared"
low = 1.0
high = 3.0
step = 0.5
default = 2.0

[[parameters]]
name = "psi"
low = 0.25
high = 2.0
log = true
default = 1.0

[[parameters]]
name = "theta"
low = 0.0
high = 1.5
default = 0.6
"""

SMALL_INPUTS = Inputs(reader_options={"frames": 4, "width": 64, "height": 48, "noise": False})


@pytest.fixture
def space_file(tmp_path: Path) -> Path:
    path = tmp_path / "small.toml"
    path.write_text(SMALL_SPACE)
    return path


@pytest.fixture
def small_space(space_file: Path):
    from evsmap.explore.space import load_space

    return load_space(space_file)
