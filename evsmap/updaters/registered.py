"""Registers evsmap's own map updaters, ``orgb`` and ``multiclass-bayes``.

The factories live here, apart from the updaters they build, so that naming and describing the
updaters (``evsmap list``, ``evsmap info``, option checks) imports neither numba nor the compiled
kernels: each factory imports its updater when it is called. Each states only the options it
adds to the octree base's (:func:`evsmap.updaters.factories.octree_factory`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from evsmap.mapping.fusion import PHI, PSI, THETA
from evsmap.registry import OCTREE, UPDATERS
from evsmap.updaters.factories import OCTREE_OPTIONS, given, octree_factory

if TYPE_CHECKING:
    from evsmap.updaters.base import OctreeUpdater
    from evsmap.updaters.orgb import ORGBMap


def orgb(**options: Any) -> ORGBMap:
    from evsmap.updaters.orgb import ORGBMap

    return ORGBMap(**options)


UPDATERS.add("orgb", octree_factory(orgb),
             takes=OCTREE,
             description="ORGBMap: OctoMap occupancy + averaged RGB (ColorOcTree), EVSMaP Table IV")

_DIRECT_ONLY = ("leaf_update", "occupancy", "discretize", "prob_hit", "prob_miss")
"""The options SSMI's generator has none of (they must keep their defaults with it)."""


def multiclass_bayes(*, front_end: str, **options: Any) -> OctreeUpdater:
    """``front_end="generator"`` (the default): SSMI's generator
    (:class:`~evsmap.updaters.mcb_generator.GeneratorMultiClassBayesMap`; ``raycast_range``,
    SSMI's clamping 1e-4 / 0.9999); ``"direct"``:
    :class:`~evsmap.updaters.multiclass_bayes.MultiClassBayesMap` (every pixel, rays to
    ``max_range``, one observation per leaf and frame; ``leaf_update``, ``occupancy``,
    ``discretize``, ``prob_hit`` / ``prob_miss``, OctoMap's clamping). ``pruned_leaves`` is
    the generator's: ``copies`` (SSMI's pruned blocks) or ``own``."""
    from evsmap.errors import InvalidDataError
    from evsmap.mapping.generator import check_front_end

    check_front_end("multiclass-bayes", front_end)
    if front_end == "generator":
        from evsmap.updaters.mcb_generator import GeneratorMultiClassBayesMap

        for option in _DIRECT_ONLY:
            if options[option] != {**OCTREE_OPTIONS, **MULTICLASS_BAYES}[option]:
                raise InvalidDataError(f"multiclass-bayes: {option} applies to -o "
                                       f"front_end=direct only (SSMI's generator has none)")
        return GeneratorMultiClassBayesMap(**given(options, *_DIRECT_ONLY))
    from evsmap.updaters.multiclass_bayes import MultiClassBayesMap

    if options["pruned_leaves"] != MULTICLASS_BAYES["pruned_leaves"]:
        raise InvalidDataError("multiclass-bayes: pruned_leaves applies to the generator front "
                               "end only (SSMI's pruned blocks)")
    return MultiClassBayesMap(**given(options, "raycast_range", "pruned_leaves"))


MULTICLASS_BAYES: dict[str, Any] = {
    "front_end": "generator", "raycast_range": 2.0, "psi": PSI, "phi": PHI, "theta": THETA,
    "leaf_update": "bayes", "pairing": "printed", "occupancy": "semantic",
    "clamp_min": None, "clamp_max": None, "pruned_leaves": "copies"}
"""What ``multiclass-bayes`` adds to the octree base's options (the clamping: the front end's
own, SSMI's with the generator)."""

UPDATERS.add("multiclass-bayes", octree_factory(multiclass_bayes, **MULTICLASS_BAYES),
             takes=OCTREE,
             description="EVSMaP: multi-class Bayesian semantic octree, SSMI's update on "
                         "the octomap_generator front end (Algorithm 1 merging nodes, "
                         "theta 0.6); -o front_end=direct for evsmap's per-leaf front end")
