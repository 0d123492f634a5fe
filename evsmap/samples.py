"""The real sample data the tests and ``evsmap reproduce`` use, by name.

Each sample is a small piece of a public dataset kept under the data root
(:func:`evsmap.paths.default_data_root`) in ``folder``; ``evsmap datasets fetch NAME`` makes it
from the official archive.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Sample:
    """One sample: its name, its path under the data root and a one-line description."""

    name: str
    folder: str
    description: str


SAMPLES: dict[str, Sample] = {s.name: s for s in (
    Sample("tum-fr1-xyz", "tum_fr1_xyz",
           "TUM RGB-D freiburg1_xyz, first 1.2 s (37 RGB + 37 depth, full ground truth)"),
    Sample("sevenscenes-100", "sevenscenes_100",
           "Microsoft 7-Scenes, first 100 frames of one sequence"),
    Sample("nyuv2-samples", "nyuv2_samples",
           "NYU Depth v2 labelled frames 000433 and 000464 (RGB, depth, 40-class labels)"),
    Sample("lidar-odometry-bag", "ros/lidar_odometry.bag",
           "ROS1 bag with PointCloud2 and Odometry (embag test data)"),
)}
