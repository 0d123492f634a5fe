"""Registers the compared map updaters: semantic_slam's ``classic-semantic`` and
``classic-semantic-max`` (:mod:`baselines.classic_semantic`, :mod:`baselines.semantic_slam`) and
the C++ OctoMap's ``octomap-cpp`` and ``octomap-color`` (:mod:`baselines.octomap_adapters`).

The factories live apart from the updaters so that naming them imports neither numba nor the
OctoMap binding; each factory imports its updater when called.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from evsmap.registry import UPDATERS

if TYPE_CHECKING:
    from baselines.octomap_adapters import OctoMapAdapter


def _classic(rule: str):
    def factory(*, resolution: float = 0.05, max_range: float = 5.0, discretize: bool = True,
                front_end: str = "generator", raycast_range: float = 2.0,
                prob_hit: float = 0.7, prob_miss: float = 0.4, clamp_min: float | None = None,
                clamp_max: float | None = None):
        from evsmap.mapping.generator import check_front_end

        check_front_end("classic-semantic", front_end)
        if front_end == "generator":
            from baselines.semantic_slam import make

            if not discretize:
                from evsmap.errors import InvalidDataError

                raise InvalidDataError("classic-semantic: semantic_slam always inserts with "
                                       "discretize on; use -o front_end=direct for "
                                       "discretize=false")

            # semantic_slam's octomap_generator.yaml clamps at 0.12 / 0.97
            return make(rule, resolution=resolution, max_range=max_range,
                        raycast_range=raycast_range, prob_hit=prob_hit, prob_miss=prob_miss,
                        clamp_min=0.12 if clamp_min is None else clamp_min,
                        clamp_max=0.97 if clamp_max is None else clamp_max)
        from baselines.classic_semantic import ClassicSemanticMap

        return ClassicSemanticMap(fusion_rule=rule, resolution=resolution, max_range=max_range,
                                  discretize=discretize, prob_hit=prob_hit, prob_miss=prob_miss,
                                  clamp_min=0.1192 if clamp_min is None else clamp_min,
                                  clamp_max=0.971 if clamp_max is None else clamp_max)

    return factory


UPDATERS.add("classic-semantic", _classic("bayes"),
             description="[14] semantic_slam: top-3 Bayesian semantic fusion + RGB (TESAMap, "
                         "TFEAGMap); -o front_end=direct for evsmap's cleaner variant")
UPDATERS.add("classic-semantic-max", _classic("max"),
             description="[14] semantic_slam: max semantic fusion + RGB; -o "
                         "front_end=direct for evsmap's cleaner variant")


def _octomap(color: bool):
    def factory(*, resolution: float = 0.05, max_range: float = 5.0, discretize: bool = True,
                prob_hit: float = 0.7, prob_miss: float = 0.4, clamp_min: float = 0.1192,
                clamp_max: float = 0.971) -> OctoMapAdapter:
        from baselines.octomap_adapters import OctoMapAdapter

        return OctoMapAdapter(color=color, resolution=resolution, max_range=max_range,
                              discretize=discretize, prob_hit=prob_hit, prob_miss=prob_miss,
                              clamp_min=clamp_min, clamp_max=clamp_max)

    return factory


UPDATERS.add("octomap-cpp", _octomap(False),
             description="OctoMap C++ OcTree via octomap-python (occupancy only, reference)")
UPDATERS.add("octomap-color", _octomap(True),
             description="OctoMap C++ ColorOcTree via octomap-python (averaged RGB, reference)")
