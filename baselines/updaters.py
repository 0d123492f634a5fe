"""Registers the compared map updaters: semantic_slam's ``classic-semantic`` and
``classic-semantic-max`` (:mod:`baselines.classic_semantic`, :mod:`baselines.semantic_slam`) and
the C++ OctoMap's ``octomap-cpp`` and ``octomap-color`` (:mod:`baselines.octomap_adapters`).

The factories live apart from the updaters so that naming them imports neither numba nor the
OctoMap binding; each factory imports its updater when called, and states only the options it
adds to the octree base's (:func:`evsmap.updaters.factories.octree_factory`).
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING, Any

from evsmap.registry import OCTREE, UPDATERS
from evsmap.updaters.factories import given, octree_factory

if TYPE_CHECKING:
    from baselines.octomap_adapters import OctoMapAdapter
    from evsmap.updaters.tree_map import OctreeMap


CLASSIC: dict[str, Any] = {"front_end": "generator", "raycast_range": 2.0, "clamp_min": None,
                           "clamp_max": None}
"""What ``classic-semantic`` adds to the octree base's options (the clamping: the front end's
own, semantic_slam's ``octomap_generator.yaml`` 0.12 / 0.97 with the generator)."""


def classic(rule: str, *, front_end: str, **options: Any) -> OctreeMap:
    """semantic_slam's map with fusion ``rule`` (``bayes``, ``max``): its own pipeline
    (:class:`~baselines.semantic_slam.SemanticSlamMap`) or, ``front_end="direct"``, evsmap's cleaner
    variant (:class:`~baselines.classic_semantic.ClassicSemanticMap`)."""
    from evsmap.mapping.generator import check_front_end

    check_front_end("classic-semantic", front_end)
    if front_end == "generator":
        from baselines.semantic_slam import SemanticSlamMap

        if not options["discretize"]:
            from evsmap.errors import InvalidDataError

            raise InvalidDataError("classic-semantic: semantic_slam always inserts with "
                                   "discretize on; use -o front_end=direct for "
                                   "discretize=false")
        return SemanticSlamMap(fusion_rule=rule, **given(options))
    from baselines.classic_semantic import ClassicSemanticMap

    return ClassicSemanticMap(fusion_rule=rule, **given(options, "raycast_range"))


UPDATERS.add("classic-semantic", octree_factory(functools.partial(classic, "bayes"), **CLASSIC),
             takes=OCTREE,
             description="[14] semantic_slam: top-3 Bayesian semantic fusion + RGB (TESAMap, "
                         "TFEAGMap); -o front_end=direct for evsmap's cleaner variant")
UPDATERS.add("classic-semantic-max", octree_factory(functools.partial(classic, "max"),
                                                    **CLASSIC),
             takes=OCTREE,
             description="[14] semantic_slam: max semantic fusion + RGB; -o "
                         "front_end=direct for evsmap's cleaner variant")


def octomap(color: bool, **options: Any) -> OctoMapAdapter:
    """The C++ OctoMap's ``OcTree`` or (``color``) ``ColorOcTree``; ``kernels`` has one value
    here, ``compiled`` (the library is C++ throughout)."""
    from baselines.octomap_adapters import OctoMapAdapter

    if options["kernels"] != "compiled":
        from evsmap.errors import InvalidDataError

        raise InvalidDataError("octomap-cpp / octomap-color: kernels=reference applies to "
                               "evsmap's updaters only (OctoMap runs in C++)")
    return OctoMapAdapter(color=color, **given(options, "kernels"))


UPDATERS.add("octomap-cpp", octree_factory(functools.partial(octomap, False)),
             takes=OCTREE,
             description="OctoMap C++ OcTree via octomap-python (occupancy only, reference)")
UPDATERS.add("octomap-color", octree_factory(functools.partial(octomap, True)),
             takes=OCTREE,
             description="OctoMap C++ ColorOcTree via octomap-python (averaged RGB, reference)")
