"""The registered updater factories: each states only what it adds, and every option of the
octree base is reachable (and listed with its default and type)."""

import inspect

import pytest

from evsmap.errors import EvsmapError
from evsmap.mapping.occupancy import OccupancyParams
from evsmap.mapping.sensor_model import OCTOMAP
from evsmap.registry import UPDATERS
from evsmap.updaters.base import OctreeUpdater
from evsmap.updaters.factories import OCTREE_OPTIONS

OCTREE_NAMES = ("orgb", "multiclass-bayes", "classic-semantic", "classic-semantic-max",
                "octomap-cpp", "octomap-color")


def test_the_base_options_are_the_base_constructors():
    params = inspect.signature(OctreeUpdater.__init__).parameters
    base = {k: p.default for k, p in params.items() if k not in ("self", "node_type", "name")}
    assert base == OCTREE_OPTIONS
    assert OccupancyParams() == OCTOMAP


@pytest.mark.parametrize("name", OCTREE_NAMES)
def test_every_base_option_is_listed_and_reaches_the_map(name):
    if name.startswith("octomap"):
        pytest.importorskip("octomap")
    params = UPDATERS.get(name).options
    assert set(OCTREE_OPTIONS) <= set(params)
    for key, default in OCTREE_OPTIONS.items():
        assert params[key].default in (default, None), key  # None: the updater's own
    updater = UPDATERS.create(name, occupancy_threshold=0.6)
    if name.startswith("octomap"):
        assert updater.tree.getOccupancyThres() == pytest.approx(0.6)
    else:
        assert updater.params.occupancy_threshold == pytest.approx(0.6)


def test_factories_check_names_and_types():
    with pytest.raises(EvsmapError, match="has no option 'bogus'.*occupancy_threshold"):
        UPDATERS.create("orgb", bogus=1)
    with pytest.raises(EvsmapError, match="option occupancy_threshold must be a number"):
        UPDATERS.create("multiclass-bayes", occupancy_threshold="high")


def test_differing_defaults():
    """The generator front ends keep their ROS nodes' clamping; direct ones OctoMap's."""
    ssmi = UPDATERS.create("multiclass-bayes")
    assert ssmi.params.clamp_min == pytest.approx(1e-4)
    direct = UPDATERS.create("multiclass-bayes", front_end="direct")
    assert (direct.params.clamp_min, direct.params.clamp_max) == (OCTOMAP.clamp_min,
                                                                  OCTOMAP.clamp_max)
    slam = UPDATERS.create("classic-semantic")
    assert slam.params.clamp_min == pytest.approx(0.12) and slam.raycast_range == 2.0
