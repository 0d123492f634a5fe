"""Registers evsmap's own map updaters, ``orgb`` and ``multiclass-bayes``.

The factories live here, apart from the updaters they build, so that naming and describing the
updaters (``evsmap list``, ``evsmap info``, option checks) imports neither numba nor the compiled
kernels: each factory imports its updater when it is called.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from evsmap.mapping.fusion import PHI, PSI, THETA
from evsmap.registry import UPDATERS

if TYPE_CHECKING:
    from evsmap.updaters.base import OctreeUpdater
    from evsmap.updaters.orgb import ORGBMap


@UPDATERS.register("orgb", description="ORGBMap: OctoMap occupancy + averaged RGB "
                                       "(ColorOcTree), EVSMaP Table IV")
def orgb(*, resolution: float = 0.05, max_range: float = 5.0, discretize: bool = True,
         prob_hit: float = 0.7, prob_miss: float = 0.4, clamp_min: float = 0.1192,
         clamp_max: float = 0.971) -> ORGBMap:
    from evsmap.updaters.orgb import ORGBMap

    return ORGBMap(resolution=resolution, max_range=max_range, discretize=discretize,
                   prob_hit=prob_hit, prob_miss=prob_miss, clamp_min=clamp_min,
                   clamp_max=clamp_max)


@UPDATERS.register("multiclass-bayes",
                   description="EVSMaP: multi-class Bayesian semantic octree, SSMI's update on "
                               "the octomap_generator front end (Algorithm 1 merging nodes, "
                               "theta 0.6); -o front_end=direct for evsmap's per-leaf front end")
def multiclass_bayes(*, front_end: str = "generator", resolution: float = 0.05,
                     max_range: float = 5.0, raycast_range: float = 2.0,
                     discretize: bool = True, psi: float = PSI, phi: float = PHI,
                     theta: float = THETA, leaf_update: str = "bayes",
                     pairing: str = "printed", occupancy: str = "semantic",
                     prob_hit: float = 0.7, prob_miss: float = 0.4,
                     clamp_min: float | None = None, clamp_max: float | None = None
                     ) -> OctreeUpdater:
    """``front_end="generator"`` (the default): SSMI's generator
    (:class:`~evsmap.updaters.mcb_generator.GeneratorMultiClassBayesMap`; ``raycast_range``,
    SSMI's clamping 1e-4 / 0.9999); ``"direct"``:
    :class:`~evsmap.updaters.multiclass_bayes.MultiClassBayesMap` (every pixel, rays to
    ``max_range``, one observation per leaf and frame; ``leaf_update``, ``occupancy``,
    ``discretize``, ``prob_hit`` / ``prob_miss``, OctoMap's clamping 0.1192 / 0.971)."""
    from evsmap.errors import InvalidDataError
    from evsmap.mapping.generator import check_front_end

    check_front_end("multiclass-bayes", front_end)
    if front_end == "generator":
        from evsmap.updaters.mcb_generator import ROS_DEFAULTS, GeneratorMultiClassBayesMap

        for option, value, default in (("leaf_update", leaf_update, "bayes"),
                                       ("occupancy", occupancy, "semantic"),
                                       ("discretize", discretize, True),
                                       ("prob_hit", prob_hit, 0.7), ("prob_miss", prob_miss, 0.4)):
            if value != default:
                raise InvalidDataError(f"multiclass-bayes: {option} applies to -o "
                                       f"front_end=direct only (SSMI's generator has none)")
        return GeneratorMultiClassBayesMap(
            psi=psi, phi=phi, theta=theta, pairing=pairing, raycast_range=raycast_range,
            resolution=resolution, max_range=max_range,
            clamp_min=ROS_DEFAULTS["clamp_min"] if clamp_min is None else clamp_min,
            clamp_max=ROS_DEFAULTS["clamp_max"] if clamp_max is None else clamp_max)
    from evsmap.updaters.multiclass_bayes import MultiClassBayesMap

    return MultiClassBayesMap(resolution=resolution, max_range=max_range, discretize=discretize,
                              psi=psi, phi=phi, theta=theta, leaf_update=leaf_update,
                              pairing=pairing, occupancy=occupancy, prob_hit=prob_hit,
                              prob_miss=prob_miss,
                              clamp_min=0.1192 if clamp_min is None else clamp_min,
                              clamp_max=0.971 if clamp_max is None else clamp_max)
