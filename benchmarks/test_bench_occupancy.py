"""Speed of the occupancy core against OctoMap C++ (octomap-python), frame by frame.

Each round integrates the next of the 37 real TUM fr1_xyz frames into one growing map (max range
4 m, discretize=True, OctoMap's sensor model), so the median round time is the median time per
frame and 1 / median the rate in Hz. Both sides start from the decoded :class:`Frame` and pay the
same back-projection (:func:`evsmap.mapping.raycast.frame_points`); OctoMap's time also includes
octomap-python copying the points into its ``Pointcloud``.
"""

from __future__ import annotations

import pytest

from evsmap.mapping.occupancy import OccupancyMap
from evsmap.mapping.raycast import frame_points
from evsmap.testing import require_module

MAX_RANGE = 4.0


@pytest.mark.parametrize("resolution", [0.05, 0.02], ids=["5cm", "2cm"])
@pytest.mark.parametrize("impl", ["evsmap", "octomap-cpp"])
def test_insert_frame(benchmark, tum_frames, impl, resolution):
    if impl == "evsmap":
        target = OccupancyMap(resolution)

        def insert(frame):
            target.insert_frame(frame, max_range=MAX_RANGE, discretize=True)
    else:
        octomap = require_module("octomap")
        target = octomap.OcTree(resolution)

        def insert(frame):
            points, origin = frame_points(frame)
            target.insertPointCloud(points, origin, MAX_RANGE, False, True)

    frames = iter(tum_frames)
    benchmark.group = f"occupancy insert_frame {resolution * 100:.0f} cm"
    benchmark.pedantic(lambda: insert(next(frames)), rounds=len(tum_frames), iterations=1,
                       warmup_rounds=0)
    leaves = target.num_leaves if impl == "evsmap" else target.getNumLeafNodes()
    benchmark.extra_info.update(frames=len(tum_frames), leaves=int(leaves),
                                update_hz=1.0 / benchmark.stats.stats.median)
