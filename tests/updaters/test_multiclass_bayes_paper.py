"""The multiclass-bayes updater as the paper defines it: occupancy derived from the class
vector, the variants as options, Algorithm 1 on inner nodes and pruning of identical leaves."""

from __future__ import annotations

import numpy as np
import pytest

from evsmap.errors import InvalidDataError
from evsmap.mapping import fusion as fu
from evsmap.mapping.keys import KEY_OFFSET, pack
from evsmap.mapping.occupancy import OccupancyMap
from evsmap.registry import READERS, SEGMENTERS, UPDATERS
from evsmap.updaters.multiclass_bayes import EMPTY_ID


@pytest.fixture(scope="module")
def observed():
    seq = READERS.create("synthetic", frames=4, width=160, height=120)
    oracle = SEGMENTERS.create("oracle", seed=2, accuracy=0.8)
    frames = [seq.frame(i) for i in range(len(seq))]
    return frames, [oracle.predict(f) for f in frames]


def _mapped(observed, **options):
    m = UPDATERS.create("multiclass-bayes", front_end="direct", resolution=0.1, max_range=4.0,
                        **options)
    for frame, obs in zip(*observed, strict=True):
        m.integrate(frame, obs)
    return m


def test_occupancy_is_the_class_vectors(observed):
    m = _mapped(observed)
    derived = fu.mcb_occupancy(m.state())
    assert np.array_equal(m.map.logodds, derived)
    # occupied (OctoMap's threshold 0.5) exactly where p(free) < 0.5 under eq. 6
    _, _, p_free = fu.mcb_probabilities(m.state())
    occupied = m.map.logodds >= 0
    assert np.array_equal(occupied, p_free <= 0.5)
    assert occupied.sum() > 100 and (~occupied).sum() > 1000
    octo = _mapped(observed, occupancy="octomap")
    assert np.array_equal(octo.map.codes, m.map.codes)  # the same rays and keys
    assert not np.array_equal(octo.map.logodds, fu.mcb_occupancy(octo.state()))


def test_the_variants_give_different_maps(observed):
    paper = _mapped(observed)
    average = _mapped(observed, leaf_update="average")
    ssmi = _mapped(observed, leaf_update="average", pairing="ssmi")
    assert np.array_equal(paper.map.codes, average.map.codes)
    lo = [m.map.payload("class_logodds") for m in (paper, average, ssmi)]
    assert not np.array_equal(lo[0], lo[1]) and not np.array_equal(lo[1], lo[2])


@pytest.mark.parametrize("option, value", [("leaf_update", "mean"), ("pairing", "swapped"),
                                           ("occupancy", "both")])
def test_bad_options_are_named(option, value):
    with pytest.raises(InvalidDataError, match=f"{option} must be one of"):
        UPDATERS.create("multiclass-bayes", front_end="direct", **{option: value})


def _siblings_map(states: list[fu.MCBState]):
    """A map whose leaves are the 8 children of one parent (plus their states)."""
    m = UPDATERS.create("multiclass-bayes", front_end="direct", resolution=0.1)
    base = np.array([KEY_OFFSET, KEY_OFFSET, KEY_OFFSET])
    keys = np.array([base + [i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)])
    codes = pack(keys)
    state = fu.MCBState(np.concatenate([s.classes for s in states]),
                        np.concatenate([s.logodds for s in states]),
                        np.concatenate([s.others for s in states]))
    m.map = OccupancyMap.from_leaves(0.1, codes, fu.mcb_occupancy(state), params=m.params)
    m._init_payloads()
    order = np.argsort(codes)
    m.store(np.arange(8), state.take(np.argsort(order)))
    return m


def _saturated(cls: int, hits: int) -> fu.MCBState:
    s = fu.MCBState.empty(1)
    for _ in range(hits):
        s = fu.mcb_observe(s, np.array([cls]))
    return s


def test_saturated_identical_siblings_are_pruned():
    m = _siblings_map([_saturated(3, 100 + 7 * i) for i in range(8)])
    tree = m.tree()
    # root ... parent: the 8 children collapse into their parent, which keeps their state
    assert tree.num_leaves == 1 and tree.num_nodes == 16
    leaf = tree.payload[tree.is_leaf][0]
    assert leaf["classes"].tolist() == [3, EMPTY_ID, EMPTY_ID]
    assert leaf["logodds"][0] == np.float32(fu.MAX_LOGODDS)


def test_differing_siblings_stay_and_the_parent_folds_them_with_algorithm1():
    states = [_saturated(3, 100) for _ in range(7)] + [_saturated(5, 4)]
    m = _siblings_map(states)
    tree = m.tree()
    assert tree.num_leaves == 8 and tree.num_nodes == 16 + 8  # root..parent, 8 leaves
    parent = tree.payload[(tree.depth == 15)][0]
    acc = states[0]
    for s in states[1:]:
        acc = fu.merge_algorithm1(acc, s, 0.6)
    ids = np.where(acc.classes[0] < 0, EMPTY_ID, acc.classes[0])
    assert parent["classes"].tolist() == ids.tolist()
    assert np.array_equal(parent["logodds"], acc.logodds[0])
    assert parent["others"] == acc.others[0]
