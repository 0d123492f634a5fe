"""EVSMaP's leaf update (eq. 7 with eq. 9's piecewise constants, SSMI ``fuseObs``), occupancy
from the class vector (eq. 5), Algorithm 1's two pairings and the inner-node fold, worked out by
hand over several frames. psi = 1, phi = -0.1, clamps +-log(0.9999 / 0.0001) = +-9.21034."""

from __future__ import annotations

import math

import numpy as np
import pytest

from evsmap.mapping import fusion as fu
from evsmap.mapping.fusion import MCBState

LN = math.log
MAXL = LN(0.9999 / 0.0001)
EMPTY_FLOOR = LN(0.1192 / 0.8808)  # OctoMap's clamping minimum, where free voxels saturate


def one(classes=(), logodds=(), others=0.0) -> MCBState:
    cls = np.full((1, 3), -1, np.int16)
    lo = np.zeros((1, 3), np.float32)
    cls[0, :len(classes)] = classes
    lo[0, :len(logodds)] = logodds
    return MCBState(cls, lo, np.array([others], np.float32))


def observe(s: MCBState, cls: int, times: int = 1) -> MCBState:
    for _ in range(times):
        s = fu.mcb_observe(s, np.array([cls]))
    return s


def occupancy(s: MCBState) -> float:
    return float(fu.mcb_occupancy(s)[0])


def test_first_hit_of_an_unknown_voxel_and_its_occupancy():
    s = observe(one(), 5)
    # initSemantics from others = 0 (unknown): class log 0.1 + 0 + psi, others log 0.9 + phi
    assert s.classes[0].tolist() == [5, -1, -1]
    assert float(s.logodds[0, 0]) == pytest.approx(LN(0.1) + 1.0, abs=1e-6)  # -1.302585
    assert float(s.others[0]) == pytest.approx(LN(0.9) - 0.1, abs=1e-6)  # -0.205361
    # eq. 5: p(occupied) = 1 - p(free); L = log(e^-1.302585 + e^-0.205361) = 0.082669 > 0
    expected = LN(math.exp(LN(0.1) + 1.0) + math.exp(LN(0.9) - 0.1))
    assert occupancy(s) == pytest.approx(expected, abs=1e-6)
    assert occupancy(s) == pytest.approx(0.082669, abs=1e-6)


def test_identical_hits_accumulate_to_the_clamp():
    s = observe(one(), 5, times=50)
    # class: -1.302585 + 49 -> capped at 9.21034 after the 12th hit; others: -0.205361 - 4.9
    assert float(s.logodds[0, 0]) == pytest.approx(MAXL, abs=1e-6)
    assert float(s.others[0]) == pytest.approx(LN(0.9) - 0.1 - 4.9, abs=1e-5)
    p, _, p_free = fu.mcb_probabilities(s)
    assert p[0, 0] > 0.9998 and p_free[0] < 1.1e-4
    # the averaging of a local node (the average variant) stays far below: 50 frames at 0.9
    local = fu.build_local(np.zeros(1, int), np.array([[5, 1, 2]]), np.array([[0.9, 0.05, 0.03]]),
                           1)
    avg = local
    for _ in range(49):
        avg = fu.merge_algorithm1(avg, local)
    p_avg, _, _ = fu.mcb_probabilities(avg)
    assert p_avg[0, 0] < 0.8


def test_eleven_hits_then_the_cap():
    s = observe(one(), 5, times=11)
    assert float(s.logodds[0, 0]) == pytest.approx(LN(0.1) + 1.0 + 10.0, abs=1e-5)  # 8.697
    s = observe(s, 5)
    assert float(s.logodds[0, 0]) == pytest.approx(MAXL, abs=1e-6)


def test_a_class_enters_the_top3_and_another_leaves_it():
    s = one([1, 2, 3], [3.0, 2.0, 0.5], 0.5)
    s = observe(s, 4)
    # 4 enters at others + log 0.8 + psi = 1.276856; 1, 2, 3 get phi: 2.9, 1.9, 0.4;
    # others: 0.5 + log 0.2 + phi = -1.209438; the 4th entry (class 3, 0.4) folds into others
    entering = 0.5 + LN(0.8) + 1.0
    folded = LN(math.exp(0.5 + LN(0.2) - 0.1) + math.exp(0.4))
    assert s.classes[0].tolist() == [1, 2, 4]
    assert s.logodds[0].tolist() == pytest.approx([2.9, 1.9, entering], abs=1e-6)
    assert float(s.others[0]) == pytest.approx(folded, abs=1e-6)  # 0.582323
    # class 3 comes back from others and pushes 4 out
    s = observe(s, 3)
    entering3 = folded + LN(0.8) + 1.0
    folded4 = LN(math.exp(folded + LN(0.2) - 0.1) + math.exp(entering - 0.1))
    assert s.classes[0].tolist() == [1, 2, 3]
    assert s.logodds[0].tolist() == pytest.approx([2.8, 1.8, entering3], abs=1e-5)
    assert float(s.others[0]) == pytest.approx(folded4, abs=1e-5)


def test_a_label_survives_contrary_frames_after_many_agreeing_ones():
    s = observe(one(), 1, times=30)
    s = observe(s, 2, times=3)
    # class 2 entered at -3.105361 + log 0.8 + 1 = -2.328505 and rose by 1 twice: -0.328505;
    # class 1 lost 0.3 from the clamp: 8.91034
    assert s.classes[0, :2].tolist() == [1, 2]
    assert s.logodds[0, :2].tolist() == pytest.approx(
        [MAXL - 0.3, LN(0.9) - 0.1 - 2.9 + LN(0.8) + 1.0 + 2.0], abs=1e-5)
    # the averaging variant: the same history flips the label within 3 contrary frames
    node = {c: fu.build_local(np.zeros(1, int), np.array([[c, 3 - c, 3]]),
                              np.array([[0.8, 0.1, 0.05]]), 1) for c in (1, 2)}
    avg = node[1]
    for _ in range(29):
        avg = fu.merge_algorithm1(avg, node[1])
    for _ in range(3):
        avg = fu.merge_algorithm1(avg, node[2])
    assert int(avg.classes[0, 0]) == 2


def test_misses_lower_every_entry_and_the_occupancy_by_phi():
    s = observe(one(), 1, times=3)
    before = occupancy(s)
    m = fu.mcb_miss(s)
    # every entry is shifted by phi (none at a floor): the occupancy log-odds by exactly phi
    assert occupancy(m) == pytest.approx(before - 0.1, abs=1e-6)
    # a voxel without classes keeps its occupancy in others, floored at OctoMap's minimum
    free = one()
    for _ in range(30):
        free = fu.mcb_miss(free, empty_min_logodds=EMPTY_FLOOR)
    assert float(free.others[0]) == pytest.approx(EMPTY_FLOOR, abs=1e-6)
    assert occupancy(free) == pytest.approx(EMPTY_FLOOR, abs=1e-6)


def test_saturated_histories_become_identical_nodes():
    """Different histories that reach the clamps store exactly equal float32 states, so 8 such
    siblings prune (the test of :mod:`tests.updaters.test_multiclass_bayes_paper` builds them)."""
    a = observe(one(), 3, times=100)
    b = observe(one(), 3, times=130)
    assert a.equals(b)[0]
    assert float(a.others[0]) == pytest.approx(-MAXL, abs=1e-6)
    f1, f2 = one(), one()
    for _ in range(25):  # 0.1 x 20 = 2.0000002 in float32 is still above -2.0000279
        f1 = fu.mcb_miss(f1, empty_min_logodds=EMPTY_FLOOR)
    for _ in range(35):
        f2 = fu.mcb_miss(f2, empty_min_logodds=EMPTY_FLOOR)
    assert f1.equals(f2)[0]


def test_observed_without_a_class():
    s = fu.mcb_observe(one([2], [1.0], -1.0), np.array([-1]))
    assert s.classes[0].tolist() == [2, -1, -1]
    assert float(s.logodds[0, 0]) == pytest.approx(0.9, abs=1e-6)
    assert float(s.others[0]) == pytest.approx(0.0, abs=1e-6)


# ------------------------------------------------------------------------------------------
# Algorithm 1: the two pairings
# ------------------------------------------------------------------------------------------
G = ([1, 2, 3], [2.0, 1.0, 0.0], -1.0)
C = ([1, 4, 2], [1.5, 1.0, 0.2], -1.5)


def test_algorithm1_as_printed():
    u = fu.merge_algorithm1(one(*G), one(*C), theta=0.6)  # pairing="printed" is the default
    # Z = {1, 2, 3, 4}: theta log 5 = 0.965663; Delta_G = -1.965663, Delta_C = -2.465663
    d_g, d_c = -1.0 - 0.6 * LN(5), -1.5 - 0.6 * LN(5)
    # 3 only in G: (Delta_G + zeta_G(3)) / 2 = -0.982831; 4 only in C: (Delta_C + 1) / 2 =
    # -0.732831; shared 1: 1.75, 2: 0.6; order 1, 2, 4, 3 -> 3 folded with (d_g + d_c) / 2
    assert u.classes[0].tolist() == [1, 2, 4]
    assert u.logodds[0].tolist() == pytest.approx([1.75, 0.6, (d_c + 1.0) / 2], abs=1e-6)
    assert float(u.logodds[0, 2]) == pytest.approx(-0.732831, abs=1e-6)
    xi = LN(math.exp((d_g + d_c) / 2) + math.exp((d_g + 0.0) / 2))
    assert float(u.others[0]) == pytest.approx(xi, abs=1e-6)
    assert float(u.others[0]) == pytest.approx(-0.727053, abs=1e-5)


def test_algorithm1_ssmi_pairing_differs_only_in_the_one_sided_classes():
    printed = fu.merge_algorithm1(one(*G), one(*C), theta=0.6)
    ssmi = fu.merge_algorithm1(one(*G), one(*C), theta=0.6, pairing="ssmi")
    d_g = -1.0 - 0.6 * LN(5)
    assert ssmi.logodds[0, :2].tolist() == printed.logodds[0, :2].tolist()  # shared classes
    assert float(ssmi.logodds[0, 2]) == pytest.approx((1.0 + d_g) / 2, abs=1e-6)  # -0.482831
    with pytest.raises(ValueError, match="pairing must be one of"):
        fu.merge_algorithm1(one(*G), one(*C), pairing="swapped")


# ------------------------------------------------------------------------------------------
# inner nodes
# ------------------------------------------------------------------------------------------
def _stack(*states: MCBState) -> MCBState:
    return MCBState(np.concatenate([s.classes for s in states]),
                    np.concatenate([s.logodds for s in states]),
                    np.concatenate([s.others for s in states]))


def test_inner_node_folds_its_children_with_algorithm1_in_child_order():
    third = one([4, 5], [0.5, 0.2], -0.5)
    children = _stack(one(*G), one(), one(*C), third, one(others=-2.0), one(others=-1.0))
    group = np.array([0, 0, 0, 0, 1, 1])
    out = fu.fold_algorithm1(children, group, 2, 0.6)
    expected = fu.merge_algorithm1(fu.merge_algorithm1(one(*G), one(*C), 0.6), third, 0.6)
    # the child without classes is skipped
    assert out.take([0]).equals(expected)[0]
    # no child with classes: the child with the highest others (OctoMap's max occupancy)
    assert out.classes[1].tolist() == [-1, -1, -1] and float(out.others[1]) == -1.0
