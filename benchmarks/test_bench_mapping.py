"""Map updaters on the real TUM fr1_xyz frames at 5 cm and 2 cm, with OctoMap C++
(``octomap-cpp``) in the same run (EVSMaP Table IV's "Runtime" for the map update).

Each round integrates the next of the 37 frames into one growing map (max range 4 m,
discretize on, OctoMap's sensor model), so the median round is the median time per frame. The
semantic updaters get the top-3 of an untrained, seeded FEAGNet-V1, computed once beforehand
(segmentation is not part of these timings; ``evsmap map`` reports it separately). The map file
size and in-memory size are stored in ``extra_info``.
"""

from __future__ import annotations

import pytest

from evsmap.measure.engine import StageTimes, rates, timed_update
from evsmap.registry import SEGMENTERS, UPDATERS

MAX_RANGE = 4.0
UPDATER_NAMES = ["octomap-cpp", "orgb", "classic-semantic", "multiclass-bayes"]


@pytest.fixture(scope="module")
def tum_observed(tum_frames):
    import torch

    torch.manual_seed(0)
    segmenter = SEGMENTERS.create("feagnet-v1")
    return [(frame, segmenter.predict(frame)) for frame in tum_frames]


@pytest.mark.parametrize("resolution", [0.05, 0.02], ids=["5cm", "2cm"])
@pytest.mark.parametrize("name", UPDATER_NAMES)
def test_integrate_frame(benchmark, tum_observed, name, resolution, tmp_path):
    updater = UPDATERS.create(name, resolution=resolution, max_range=MAX_RANGE)
    pairs = iter(tum_observed)
    times = StageTimes()  # the engine's timed update (pytest-benchmark times the round too)

    def integrate():
        frame, observation = next(pairs)
        timed_update(updater, frame, observation if updater.uses_semantics else None, times)

    benchmark.group = f"map update {resolution * 100:.0f} cm"
    benchmark.pedantic(integrate, rounds=len(tum_observed), iterations=1, warmup_rounds=0)
    stats = updater.stats()
    benchmark.extra_info.update(
        frames=len(tum_observed), update_hz=1.0 / benchmark.stats.stats.median,
        engine_update_hz=rates(times.get("update"))[0],
        map_bytes=updater.write(tmp_path / "map.ot"),
        octomap_memory_bytes=stats.octomap_memory_bytes,
        nodes=stats.nodes, leaves=stats.leaves)
