"""The tree-level base and its two storages, the shared front ends, and the octree's options
written once (issue 55)."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from evsmap.mapping.front_end import GeneratorFrontEnd
from evsmap.mapping.options import OCTREE_DEFAULTS, OctreeOptions
from evsmap.registry import READERS, SEGMENTERS, UPDATERS
from evsmap.updaters.base import OctreeUpdater
from evsmap.updaters.tree_map import OctreeMap


@pytest.fixture(scope="module")
def observed():
    seq = READERS.create("synthetic", frames=2, width=80, height=60)
    oracle = SEGMENTERS.create("oracle")
    frames = [seq.frame(i) for i in range(len(seq))]
    return frames, [oracle.predict(f) for f in frames]


def test_the_node_pool_is_a_sibling_storage_of_the_leaf_arrays():
    from baselines.semantic_slam import SemanticSlamMap

    slam = UPDATERS.create("classic-semantic")
    assert isinstance(slam, SemanticSlamMap) and isinstance(slam, OctreeMap)
    assert not isinstance(slam, OctreeUpdater)
    # restore is written once, on the tree-level base
    assert SemanticSlamMap.restore is OctreeMap.restore is OctreeUpdater.restore
    # the leaf view is the tree's, read only: nothing replaces the pool's storage
    with pytest.raises(AttributeError):
        slam.map = slam.leaves()


def test_the_pool_restores_through_the_base(observed, tmp_path):
    frames, observations = observed
    slam = UPDATERS.create("classic-semantic", resolution=0.1)
    for frame, obs in zip(frames, observations, strict=True):
        slam.integrate(frame, obs)
    slam.write(tmp_path / "s.ot")
    again = UPDATERS.create("classic-semantic", resolution=0.1).restore(tmp_path / "s.ot")
    again.write(tmp_path / "again.ot")
    assert (tmp_path / "again.ot").read_bytes() == (tmp_path / "s.ot").read_bytes()
    assert np.array_equal(again.map.codes, slam.map.codes)
    with pytest.raises(Exception, match="resolution 0.1 m, this map uses 0.2"):
        UPDATERS.create("classic-semantic", resolution=0.2).restore(tmp_path / "s.ot")


@pytest.mark.parametrize("name", ["classic-semantic", "multiclass-bayes"])
def test_both_generator_updaters_call_the_shared_front_end(monkeypatch, observed, name):
    frames, observations = observed
    calls = []
    real = GeneratorFrontEnd.cloud

    def counted(self, frame, fields):
        cloud = real(self, frame, fields)
        calls.append(len(cloud.centroids))
        return cloud

    monkeypatch.setattr(GeneratorFrontEnd, "cloud", counted)
    updater = UPDATERS.create(name, resolution=0.1)
    updater.integrate(frames[0], observations[0])
    assert len(calls) == 1 and calls[0] > 0
    assert updater.front_end_counts()["centroids"] == calls


def test_the_default_leaf_size_is_read_from_one_place():
    from baselines.octomap_adapters import OctoMapAdapter
    from baselines.semantic_slam import ROS_DEFAULTS
    from evsmap.cli.map_cmd import add_parser
    from evsmap.updaters.factories import OCTREE_OPTIONS
    from evsmap.updaters.mcb_generator import GeneratorMultiClassBayesMap

    resolution = OCTREE_DEFAULTS.resolution
    assert OCTREE_OPTIONS == OCTREE_DEFAULTS.as_options()
    for cls in (OctreeMap, GeneratorMultiClassBayesMap, OctoMapAdapter):
        assert inspect.signature(cls.__init__).parameters["resolution"].default == resolution
    assert ROS_DEFAULTS["resolution"] == resolution
    assert UPDATERS.create("orgb").options == OCTREE_DEFAULTS
    import argparse

    parser = argparse.ArgumentParser()
    add_parser(parser.add_subparsers())
    assert parser.parse_args(["map", "synthetic", "--updater", "orgb"]).resolution == resolution


def test_the_options_are_one_frozen_dataclass():
    updater = UPDATERS.create("multiclass-bayes", front_end="direct", resolution=0.1,
                              max_range=3.0, prob_hit=0.8)
    assert isinstance(updater.options, OctreeOptions)
    assert (updater.options.resolution, updater.options.max_range,
            updater.options.sensor.prob_hit) == (0.1, 3.0, 0.8)
    with pytest.raises(AttributeError):
        updater.options.resolution = 0.2
