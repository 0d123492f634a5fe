"""The octree's options - leaf size, ranges, sensor model, kernels - in one frozen dataclass,
the one place their defaults are written.

The updaters' constructors (:class:`~evsmap.updaters.base.OctreeUpdater` and the compared
systems), the registered factories (:data:`evsmap.updaters.factories.OCTREE_OPTIONS`) and the
command line (``evsmap map --resolution``) all read :data:`OCTREE_DEFAULTS`. The module needs only
numpy (through the sensor model), so naming and describing the updaters can state the defaults
without loading the compiled kernels.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

from evsmap.mapping.sensor_model import OCTOMAP, OccupancyParams

if TYPE_CHECKING:
    from evsmap.mapping.kernels import Kernels

__all__ = ["OCTREE_DEFAULTS", "OctreeOptions"]


@dataclass(frozen=True)
class OctreeOptions:
    """What every octree map is built with.

    Attributes:
        resolution: leaf edge length, metres.
        max_range: sensor max range, metres (negative: unlimited).
        discretize: reduce the end points to unique voxel centres before ray casting (OctoMap's
            ``discretize`` flag).
        sensor: OctoMap's sensor model (hit, miss, clamping, occupancy threshold).
        kernels: ``"compiled"`` (numba) or ``"reference"`` (numpy) update loops.
    """

    resolution: float = 0.05
    max_range: float = 5.0
    discretize: bool = True
    sensor: OccupancyParams = field(default=OCTOMAP)
    kernels: Kernels = "compiled"

    def as_options(self) -> dict[str, float | bool | str]:
        """The options as an updater's constructor takes them, the sensor model's flattened:
        ``resolution``, ``max_range``, ``discretize``, ``prob_hit`` ... ``kernels``."""
        return {"resolution": self.resolution, "max_range": self.max_range,
                "discretize": self.discretize, **asdict(self.sensor), "kernels": self.kernels}


OCTREE_DEFAULTS = OctreeOptions()
"""The defaults of every octree updater (the paper's 5 cm leaves, OctoMap's 5 m range and sensor
model, the compiled kernels)."""
