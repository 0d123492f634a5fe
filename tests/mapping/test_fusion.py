"""Per-voxel fusion rules: hand-computed cases (arithmetic in the comments) and the vectorised
functions against straightforward per-voxel reference implementations written here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from evsmap.mapping import fusion as fu
from evsmap.mapping.fusion import MCBState

LN = math.log
MAXL = LN(0.9999 / 0.0001)  # 9.2102
MINL = -MAXL


def state(rows: list[tuple[list[int], list[float], float]]) -> MCBState:
    """MCBState from (classes, logodds, others) rows; classes padded with -1 to 3 slots."""
    cls = np.full((len(rows), 3), -1, np.int16)
    lo = np.zeros((len(rows), 3), np.float32)
    ot = np.zeros(len(rows), np.float32)
    for i, (c, v, o) in enumerate(rows):
        cls[i, :len(c)] = c
        lo[i, :len(v)] = v
        ot[i] = o
    return MCBState(cls, lo, ot)


def approx(x, rel=1e-5, abs=1e-5):
    return pytest.approx(x, rel=rel, abs=abs)


# ------------------------------------------------------------------------------------------
# colour
# ------------------------------------------------------------------------------------------
def test_integrate_color_with_occupancy_07():
    prev = np.array([[100, 200, 50], [100, 200, 50]], np.uint8)
    new = np.array([[200, 0, 255], [200, 0, 255]], np.uint8)
    out = fu.integrate_color(prev, np.array([True, False]), np.array([0.7, 0.7]), new)
    # r = 100 * 0.7 + 200 * (0.99 - 0.7) = 70 + 58 = 128
    # g = 200 * 0.7 + 0 * 0.29 = 140
    # b = 50 * 0.7 + 255 * 0.29 = 35 + 73.95 = 108.95 -> (uint8_t) truncates to 108
    assert out[0].tolist() == [128, 140, 108]
    # no colour yet: the new colour is copied
    assert out[1].tolist() == [200, 0, 255]
    assert out.dtype == np.uint8


def test_color_is_set_means_not_white():
    rgb = np.array([[255, 255, 255], [255, 254, 255], [0, 0, 0]], np.uint8)
    assert fu.color_is_set(rgb).tolist() == [False, True, True]


def test_average_node_color_integer_mean():
    prev = np.array([[100, 0, 255]], np.uint8)
    new = np.array([[201, 1, 254]], np.uint8)
    # (100 + 201) / 2 = 150 (int), (0 + 1) / 2 = 0, (255 + 254) / 2 = 254
    assert fu.average_node_color(prev, np.array([True]), new)[0].tolist() == [150, 0, 254]
    assert fu.average_node_color(prev, np.array([False]), new)[0].tolist() == [201, 1, 254]


def test_average_child_color():
    kids = np.zeros((2, 8, 3), np.uint8)
    kids[0, 0] = [10, 20, 30]
    kids[0, 3] = [11, 21, 32]
    kids[0, 5] = [200, 200, 200]  # exists but masked out (no colour)
    mask = np.zeros((2, 8), bool)
    mask[0, [0, 3]] = True
    out = fu.average_color(kids, mask)
    # (10 + 11) / 2 = 10, (20 + 21) / 2 = 20, (30 + 32) / 2 = 31 in integer division
    assert out[0].tolist() == [10, 20, 31]
    # no child with a colour: white
    assert out[1].tolist() == [255, 255, 255]


# ------------------------------------------------------------------------------------------
# multi-class Bayesian hit / miss
# ------------------------------------------------------------------------------------------
def test_mcb_hit_sequence_new_class_enters_and_sorts():
    s = MCBState.empty(1)  # others = 0 (unknown)
    s = fu.mcb_hit(s, np.array([5]))
    # init: l5 = log 0.1 + 0 + 1 = -1.302585; others = log 0.9 + 0 - 0.1 = -0.205361
    assert s.classes[0].tolist() == [5, -1, -1]
    assert s.logodds[0, 0] == approx(LN(0.1) + 1)
    assert s.others[0] == approx(LN(0.9) - 0.1)
    s = fu.mcb_hit(s, np.array([5]))
    # l5 = -0.302585; others = -0.305361
    l5, ot = LN(0.1) + 2, LN(0.9) - 0.2
    assert s.logodds[0, 0] == approx(l5) and s.others[0] == approx(ot)
    s = fu.mcb_hit(s, np.array([7]))
    # 5 not observed: l5 = -0.402585; 7 enters at others + log 0.8 + 1 = 0.471496;
    # others = -0.305361 + log 0.2 - 0.1 = -2.014799; 7 sorts first
    l5, l7, ot = l5 - 0.1, ot + LN(0.8) + 1, ot + LN(0.2) - 0.1
    assert s.classes[0].tolist() == [7, 5, -1]
    assert s.logodds[0, :2].tolist() == approx([l7, l5])
    assert s.others[0] == approx(ot)
    assert l7 == approx(0.471496) and ot == approx(-2.014799)
    # occupancy L = log(e^0.471496 + e^-0.402585 + e^-2.014799) = log(2.404365) = 0.877282
    assert fu.mcb_occupancy(s)[0] == approx(0.877282, rel=1e-4)
    p_cls, p_oth, p_free = fu.mcb_probabilities(s)
    z = 1 + math.exp(l7) + math.exp(l5) + math.exp(ot)  # eq. 6, free has log-odds 0
    assert p_free[0] == approx(1 / z) and p_cls[0, 0] == approx(math.exp(l7) / z)
    assert p_cls[0, 2] == 0 and p_oth[0] == approx(math.exp(ot) / z)
    s = fu.mcb_miss(s)
    # miss: every entry - 0.1
    assert s.logodds[0, :2].tolist() == approx([l7 - 0.1, l5 - 0.1])
    assert s.others[0] == approx(ot - 0.1)


def test_mcb_hit_fourth_class_is_folded_into_others():
    s = state([([1, 2, 3], [2.0, -3.0, -4.0], 1.0), ([7, 5, 8], [0.371496, -0.502585,
                                                                   -1.237942], -3.724237)])
    s = fu.mcb_hit(s, np.array([4, 9]))
    # row 0: l1 = 1.9, l2 = -3.1, l3 = -4.1; 4 enters at 1 + log 0.8 + 1 = 1.776856;
    # others = 1 + log 0.2 - 0.1 = -0.709438; order 1, 4, 2, 3 -> 3 folded:
    # others = log(e^-0.709438 + e^-4.1) = log(0.491903 + 0.016573) = -0.676304
    assert s.classes[0].tolist() == [1, 4, 2]
    assert s.logodds[0].tolist() == approx([1.9, 2 + LN(0.8), -3.1])
    assert s.others[0] == approx(LN(math.exp(LN(0.2) + 0.9) + math.exp(-4.1)))
    assert s.others[0] == approx(-0.676304, rel=1e-4)
    # row 1: 9 enters at -3.724237 + log 0.8 + 1 = -2.947381, below l8 = -1.337942, so the
    # new class itself is folded: others = log(e^(-3.724237 + log 0.2 - 0.1) + e^-2.947381)
    #                                      = log(0.004367 + 0.052490) = -2.867444
    assert s.classes[1].tolist() == [7, 5, 8]
    assert s.logodds[1].tolist() == approx([0.271496, -0.602585, -1.337942])
    assert s.others[1] == approx(-2.867444, rel=1e-4)


def test_mcb_clamps():
    s = state([([1, 2], [9.0, -9.15], -9.2), ([3], [-9.15], 9.2)])
    hit = fu.mcb_hit(s, np.array([1, 3]))
    # 9 + 1 capped at 9.2103; -9.15 - 0.1 floored at -9.2103; others floored / capped
    assert hit.logodds[0, :2].tolist() == approx([MAXL, MINL])
    assert hit.others[0] == approx(MINL)
    assert hit.logodds[1, 0] == approx(-8.15) and hit.others[1] == approx(9.1)
    miss = fu.mcb_miss(s)
    assert miss.logodds[0, :2].tolist() == approx([8.9, MINL]) and miss.others[0] == approx(MINL)


# ------------------------------------------------------------------------------------------
# Algorithm 1 and SSMI merges
# ------------------------------------------------------------------------------------------
def test_algorithm1_shared_classes():
    g = state([([1, 2, 3], [2.0, 1.0, 0.0], -1.0)])
    c = state([([1, 2, 3], [1.0, 0.5, -0.5], -2.0)])
    u = fu.merge_algorithm1(g, c, theta=0.6, pairing="ssmi")
    # Z = {1, 2, 3}: theta log(1 + 3) = 0.6 * 1.386294 = 0.831777
    # Delta_G = -1.831777, Delta_C = -2.831777
    # shared: 1: (2 + 1) / 2 = 1.5, 2: (1 + 0.5) / 2 = 0.75, 3: (0 - 0.5) / 2 = -0.25
    # nothing folded: xi_U = log(exp((Delta_G + Delta_C) / 2)) = -2.331777
    assert u.classes[0].tolist() == [1, 2, 3]
    assert u.logodds[0].tolist() == approx([1.5, 0.75, -0.25])
    assert u.others[0] == approx(-1.5 - 0.6 * LN(4))
    assert u.others[0] == approx(-2.331777)


def test_algorithm1_class_missing_from_each_side():
    g = state([([1, 2, 3], [2.0, 1.0, 0.0], -1.0)])
    c = state([([1, 4, 2], [1.5, 1.0, 0.2], -1.5)])
    u = fu.merge_algorithm1(g, c, theta=0.6, pairing="ssmi")
    # Z = {1, 2, 3, 4}: 0.6 log 5 = 0.965663; Delta_G = -1.965663, Delta_C = -2.465663
    d_g, d_c = -1.0 - 0.6 * LN(5), -1.5 - 0.6 * LN(5)
    # 1: (2 + 1.5) / 2 = 1.75; 2: (1 + 0.2) / 2 = 0.6
    # 3 (only in G): (0 + Delta_C) / 2 = -1.232831   [as printed it would be (0 + Delta_G) / 2]
    # 4 (only in C): (1 + Delta_G) / 2 = -0.482831   [as printed: (1 + Delta_C) / 2]
    # order 1, 2, 4, 3 -> 3 folded: xi_U = log(exp((Delta_G + Delta_C) / 2) + exp(-1.232831))
    #                                    = log(0.109100 + 0.291468) = -0.914873
    assert u.classes[0].tolist() == [1, 2, 4]
    assert u.logodds[0].tolist() == approx([1.75, 0.6, (1 + d_g) / 2])
    assert u.logodds[0, 2] == approx(-0.482831)
    xi = LN(math.exp((d_g + d_c) / 2) + math.exp(d_c / 2))
    assert u.others[0] == approx(xi)
    assert u.others[0] == approx(-0.914873, rel=1e-4)


def test_algorithm1_punishment_lets_shared_classes_win():
    # G holds 3 and 1; C holds 2 and 1. Without punishment (theta = 0) the C-only class 2
    # outranks the class 1 that both hold; with theta = 0.6 the shared class ranks first.
    g = state([([3, 1], [1.0, 0.8], 0.5)])
    c = state([([2, 1], [1.2, 0.8], 0.5)])
    # theta 0: Delta = 0.5; 2 -> (1.2 + 0.5) / 2 = 0.85, 1 -> 0.8, 3 -> (1 + 0.5) / 2 = 0.75
    assert fu.merge_algorithm1(g, c, theta=0.0, pairing="ssmi").classes[0].tolist() == [2, 1, 3]
    # theta 0.6: Delta = 0.5 - 0.6 log 4 = -0.331777
    # 1 -> 0.8, 2 -> (1.2 - 0.331777) / 2 = 0.434111, 3 -> (1 - 0.331777) / 2 = 0.334111
    u = fu.merge_algorithm1(g, c, theta=0.6, pairing="ssmi")
    assert u.classes[0].tolist() == [1, 2, 3]
    assert u.logodds[0].tolist() == approx([0.8, 0.434111, 0.334111], rel=1e-4)


def test_merge_ssmi_rule():
    g = state([([1, 2, 3], [2.0, 1.0, 0.0], -1.0)])
    c = state([([1, 4, 2], [1.5, 1.0, 0.2], -1.5)])
    u = fu.merge_ssmi(g, c)
    # each node misses one class: others - log 2
    d_g, d_c = -1.0 - LN(2), -1.5 - LN(2)
    # 3 -> (0 + d_c) / 2 = -1.096574, 4 -> (1 + d_g) / 2 = -0.346574, 3 folded
    assert u.classes[0].tolist() == [1, 2, 4]
    assert u.logodds[0].tolist() == approx([1.75, 0.6, (1 + d_g) / 2])
    assert u.others[0] == approx(LN(math.exp((d_g + d_c) / 2) + math.exp(d_c / 2)))


def test_merge_of_voxels_without_classes_averages_others():
    g = MCBState.empty(1, others=-1.0)
    c = MCBState.empty(1, others=-2.0)
    # Z empty: log(1 + 0) = 0, xi_U = (-1 - 2) / 2
    u = fu.merge_algorithm1(g, c, pairing="ssmi")
    assert u.classes[0].tolist() == [-1, -1, -1] and u.others[0] == approx(-1.5)


# ------------------------------------------------------------------------------------------
# local map
# ------------------------------------------------------------------------------------------
def test_build_local_means_the_points():
    vi = np.array([0, 0, 2])
    cls = np.array([[1, 2, 3], [2, 1, 4], [5, 6, 7]])
    pr = np.array([[0.6, 0.2, 0.1], [0.5, 0.3, 0.1], [0.9, 0.05, 0.01]])
    s = fu.build_local(vi, cls, pr, 4, hit=1.0)
    # voxel 0: mean 1: (0.6 + 0.3) / 2 = 0.45, 2: (0.2 + 0.5) / 2 = 0.35, 3: 0.05, 4: 0.05
    # (tie -> smaller id 3); others = 1 - 0.85 = 0.15; l = 1 + log p
    assert s.classes[0].tolist() == [1, 2, 3]
    assert s.logodds[0].tolist() == approx([1 + LN(0.45), 1 + LN(0.35), 1 + LN(0.05)])
    assert s.others[0] == approx(1 + LN(0.15))
    # the node's occupancy log-odds is exactly the hit: log(0.45 + 0.35 + 0.05 + 0.15) = 0
    assert fu.mcb_occupancy(s)[0] == approx(1.0)
    # voxel 2: one point, others = 1 - 0.96 = 0.04
    assert s.classes[2].tolist() == [5, 6, 7]
    assert s.others[2] == approx(1 + LN(0.04))
    # voxels without points: empty and unknown
    assert s.classes[1].tolist() == [-1, -1, -1] and s.others[1] == 0
    assert s.classes[3].tolist() == [-1, -1, -1]


# ------------------------------------------------------------------------------------------
# vectorised == per-voxel reference on random states
# ------------------------------------------------------------------------------------------
def ref_hit(c, lo, ot, obs, psi=1.0, phi=-0.1):
    entries = [[ci, li] for ci, li in zip(c, lo, strict=True) if ci >= 0]
    if not entries:
        first = min(max(LN(0.1) + ot + psi, MINL), MAXL)
        return [obs, -1, -1], [first, 0.0, 0.0], max(LN(0.9) + ot + phi, MINL)
    found = False
    for e in entries:
        if e[0] == obs:
            found = True
            e[1] = min(e[1] + psi, MAXL)
        else:
            e[1] = max(e[1] + phi, MINL)
    others = ot
    if not found:
        entries.append([obs, min(ot + LN(0.8) + psi, MAXL)])
        others = ot + LN(0.2) + phi
        entries.sort(key=lambda e: -e[1])
        if len(entries) > 3:
            others = LN(math.exp(others) + math.exp(entries[-1][1]))
            entries = entries[:3]
    else:
        others = ot + phi
        entries.sort(key=lambda e: -e[1])
    others = min(max(others, MINL), MAXL)
    entries += [[-1, 0.0]] * (3 - len(entries))
    return [e[0] for e in entries], [e[1] for e in entries], others


def ref_merge(g, c, theta=None):
    """Algorithm 1 in the reading of the module notes (theta) or SSMI's rule (theta None)."""
    (gc, gl, go), (cc, cl, co) = g, c
    dg = {a: b for a, b in zip(gc, gl, strict=True) if a >= 0}
    dc = {a: b for a, b in zip(cc, cl, strict=True) if a >= 0}
    z = list(dg) + [a for a in dc if a not in dg]
    if theta is None:
        delta_g = go - LN(1 + len(z) - len(dg))
        delta_c = co - LN(1 + len(z) - len(dc))
    else:
        delta_g = go - theta * LN(1 + len(z))
        delta_c = co - theta * LN(1 + len(z))
    merged = []
    for a in z:
        if a in dg and a not in dc:
            merged.append([a, (dg[a] + delta_c) / 2])
        elif a in dc and a not in dg:
            merged.append([a, (dc[a] + delta_g) / 2])
        else:
            merged.append([a, (dg[a] + dc[a]) / 2])
    merged.sort(key=lambda e: -e[1])
    acc = math.exp((delta_g + delta_c) / 2)
    for e in merged[3:]:
        acc += math.exp(e[1])
    merged = [[a, min(max(v, MINL), MAXL)] for a, v in merged[:3]]
    merged += [[-1, 0.0]] * (3 - len(merged))
    return [e[0] for e in merged], [e[1] for e in merged], min(max(LN(acc), MINL), MAXL)


def random_state(rng, m, n_ids=6, empty_share=0.1):
    cls = np.full((m, 3), -1, np.int16)
    lo = np.zeros((m, 3), np.float32)
    for i in range(m):
        n = 0 if rng.random() < empty_share else int(rng.choice([1, 2, 3, 3, 3]))
        cls[i, :n] = rng.choice(n_ids, size=n, replace=False)
        lo[i, :n] = np.sort(rng.uniform(-5, 5, n))[::-1]
    return MCBState(cls, lo, rng.uniform(-5, 3, m).astype(np.float32))


def test_mcb_hit_and_miss_match_reference_on_random_states():
    rng = np.random.default_rng(2)
    m = 500
    s = random_state(rng, m)
    obs = rng.integers(0, 6, m)
    out = fu.mcb_hit(s, obs)
    miss = fu.mcb_miss(s)
    for i in range(m):
        rc, rl, ro = ref_hit(s.classes[i].tolist(), s.logodds[i].astype(float).tolist(),
                             float(s.others[i]), int(obs[i]))
        assert out.classes[i].tolist() == rc, i
        assert out.logodds[i].tolist() == approx(rl), i
        assert out.others[i] == approx(ro), i
        valid = s.classes[i] >= 0
        want = np.where(valid, np.maximum(s.logodds[i].astype(float) - 0.1, MINL), 0.0)
        assert miss.logodds[i].tolist() == approx(want.tolist())
        assert miss.others[i] == approx(max(float(s.others[i]) - 0.1, MINL))


def test_merges_match_reference_on_random_states():
    rng = np.random.default_rng(3)
    m = 500
    g, c = random_state(rng, m), random_state(rng, m)
    alg1 = fu.merge_algorithm1(g, c, theta=0.6, pairing="ssmi")
    ssmi = fu.merge_ssmi(g, c)
    for i in range(m):
        gi = (g.classes[i].tolist(), g.logodds[i].astype(float).tolist(), float(g.others[i]))
        ci = (c.classes[i].tolist(), c.logodds[i].astype(float).tolist(), float(c.others[i]))
        for got, theta in ((alg1, 0.6), (ssmi, None)):
            rc, rl, ro = ref_merge(gi, ci, theta)
            assert got.classes[i].tolist() == rc, i
            assert got.logodds[i].tolist() == approx(rl), i
            assert got.others[i] == approx(ro), i


def test_build_local_matches_reference_on_random_points():
    rng = np.random.default_rng(4)
    n_vox, n_pts = 50, 600
    vi = rng.integers(0, n_vox, n_pts)
    cls = np.stack([rng.choice(12, 3, replace=False) for _ in range(n_pts)])
    raw = rng.dirichlet(np.ones(5), n_pts)[:, :3]
    pr = -np.sort(-raw, axis=1)
    s = fu.build_local(vi, cls, pr, n_vox)
    for v in range(n_vox):
        pts = np.flatnonzero(vi == v)
        if pts.size == 0:
            assert s.classes[v].tolist() == [-1, -1, -1] and s.others[v] == 0
            continue
        sums: dict[int, float] = {}
        for p in pts:
            for c, q in zip(cls[p], pr[p], strict=True):
                sums[int(c)] = sums.get(int(c), 0.0) + float(q)
        ranked = sorted(((q / pts.size, c) for c, q in sums.items()),
                        key=lambda e: (-e[0], e[1]))[:3]
        assert s.classes[v].tolist() == [c for _, c in ranked] + [-1] * (3 - len(ranked))
        want = [min(max(1 + LN(max(q, 1e-4)), MINL), MAXL) for q, _ in ranked]
        assert s.logodds[v, :len(ranked)].tolist() == approx(want)
        rest = max(1 - sum(q for q, _ in ranked), 1e-4)
        assert s.others[v] == approx(1 + LN(rest))


def test_colour_matches_reference_on_random_voxels():
    rng = np.random.default_rng(5)
    m = 200
    prev = rng.integers(0, 256, (m, 3), dtype=np.uint8)
    new = rng.integers(0, 256, (m, 3), dtype=np.uint8)
    was_set = rng.random(m) < 0.8
    p = rng.uniform(0.12, 0.97, m)
    out = fu.integrate_color(prev, was_set, p, new)
    kids = rng.integers(0, 256, (m, 8, 3), dtype=np.uint8)
    mask = rng.random((m, 8)) < 0.5
    avg = fu.average_color(kids, mask)
    for i in range(m):
        if was_set[i]:
            want = [int(float(a) * p[i] + float(b) * (0.99 - p[i]))
                    for a, b in zip(prev[i], new[i], strict=True)]
        else:
            want = new[i].tolist()
        assert out[i].tolist() == want
        chosen = [kids[i, j] for j in range(8) if mask[i, j]]
        if chosen:
            want = [sum(int(k[ch]) for k in chosen) // len(chosen) for ch in range(3)]
        else:
            want = [255, 255, 255]
        assert avg[i].tolist() == want


def test_mcb_state_validates_shapes():
    with pytest.raises(ValueError, match="MCBState"):
        MCBState(np.zeros((2, 3)), np.zeros((2, 2)), np.zeros(2))
    with pytest.raises(ValueError, match="one class per voxel"):
        fu.mcb_hit(MCBState.empty(2), np.array([1]))
    with pytest.raises(ValueError, match="global voxels"):
        fu.merge_algorithm1(MCBState.empty(2), MCBState.empty(3))
