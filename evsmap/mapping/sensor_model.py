"""OctoMap's sensor model: :class:`OccupancyParams`, the one place its numbers are written.

Every updater, the ``.ot`` writer and the registered factories take their defaults from it. The
module needs only numpy, so that naming and describing the updaters (``evsmap list``, option
checks) can state them without loading the compiled kernels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def logodds(probability: float) -> float:
    """``log(p / (1 - p))`` rounded to ``float32``, as OctoMap's ``logodds`` (returned as a
    Python float holding the ``float32`` value)."""
    return float(np.float32(math.log(probability / (1.0 - probability))))


@dataclass(frozen=True)
class OccupancyParams:
    """OctoMap's sensor model; the defaults are OctoMap's.

    Attributes:
        prob_hit: probability of an end point's voxel being occupied (> 0.5).
        prob_miss: probability of a traversed voxel being occupied (< 0.5).
        clamp_min, clamp_max: the probabilities at which log-odds are clamped.
        occupancy_threshold: voxels at or above it are occupied.
    """

    prob_hit: float = 0.7
    prob_miss: float = 0.4
    clamp_min: float = 0.1192
    clamp_max: float = 0.971
    occupancy_threshold: float = 0.5

    def __post_init__(self) -> None:
        for name in ("prob_hit", "prob_miss", "clamp_min", "clamp_max", "occupancy_threshold"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.floating, np.integer)):
                raise ValueError(f"{name} must be a number, got {v!r}")
            if not 0.0 < v < 1.0:
                raise ValueError(f"{name} must be a probability strictly between 0 and 1, got {v}")
            object.__setattr__(self, name, float(v))
        if not self.prob_hit > 0.5:
            raise ValueError(f"prob_hit must be above 0.5 (a hit raises occupancy), "
                             f"got {self.prob_hit}")
        if not self.prob_miss < 0.5:
            raise ValueError(f"prob_miss must be below 0.5 (a miss lowers occupancy), "
                             f"got {self.prob_miss}")
        if not self.clamp_min < self.clamp_max:
            raise ValueError(f"clamp_min ({self.clamp_min}) must be below clamp_max "
                             f"({self.clamp_max})")

    @property
    def hit_logodds(self) -> float:
        return logodds(self.prob_hit)

    @property
    def miss_logodds(self) -> float:
        return logodds(self.prob_miss)

    @property
    def clamp_min_logodds(self) -> float:
        return logodds(self.clamp_min)

    @property
    def clamp_max_logodds(self) -> float:
        return logodds(self.clamp_max)

    @property
    def threshold_logodds(self) -> float:
        return logodds(self.occupancy_threshold)


OCTOMAP = OccupancyParams()
"""OctoMap's own sensor model (the defaults of :class:`OccupancyParams`)."""
