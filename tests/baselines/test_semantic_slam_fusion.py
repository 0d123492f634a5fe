"""semantic_slam's max and Bayesian fusion rules (baselines.semantic_slam_fusion): worked
cases from the C++ and a per-voxel transcription on random states."""

from __future__ import annotations

import numpy as np
import pytest

from baselines import semantic_slam_fusion as fu


def approx(x, rel=1e-5, abs=1e-5):
    return pytest.approx(x, rel=rel, abs=abs)


# ------------------------------------------------------------------------------------------
# semantic_slam max / Bayesian fusion
# ------------------------------------------------------------------------------------------
def test_fuse_max_cases():
    c1 = np.array([4, 4, 4, -1, 4])
    p1 = np.array([0.6, 0.6, 0.5, 0.0, 0.9], np.float32)
    c2 = np.array([4, 7, 7, 3, -1])
    p2 = np.array([0.8, 0.8, 0.5, 0.4, 0.0], np.float32)
    cls, conf = fu.fuse_max(c1, p1, c2, p2)
    # same class: (0.6 + 0.8) / 2 = 0.7
    # different: keep 7 (0.8 > 0.6), 0.8 * 0.9 = 0.72
    # tie 0.5 vs 0.5: `s1 > s2 ? s1 : s2` keeps the second, 0.5 * 0.9 = 0.45
    # empty first / empty second: the other side unchanged
    assert cls.tolist() == [4, 7, 7, 3, 4]
    assert conf.tolist() == approx([0.7, 0.72, 0.45, 0.4, 0.9])


def test_fuse_bayes_class_missing_from_one_side():
    c1 = np.array([[1, 2, 3]])
    f1 = np.array([[0.5, 0.3, 0.1]])  # o1 = 1 - 0.9 = 0.1
    c2 = np.array([[1, 2, 4]])
    f2 = np.array([[0.6, 0.2, 0.12]])  # o2 = 1 - 0.92 = 0.08
    cls, conf = fu.fuse_bayes(c1, f1, c2, f2)
    # s1's classes in s2: 1 -> 0.6, 2 -> 0.2, 3 missing -> 0.8 * o2 = 0.064, o2 = 0.016
    # s2's new class 4 -> s1 side 0.8 * o1 = 0.08, o1 = 0.02
    # products: 1: 0.5*0.6 = 0.30, 2: 0.3*0.2 = 0.06, 3: 0.1*0.064 = 0.0064,
    #           4: 0.08*0.12 = 0.0096, others: 0.02*0.016 = 0.00032; sum = 0.37632
    total = 0.30 + 0.06 + 0.0064 + 0.0096 + 0.00032
    assert cls.tolist() == [[1, 2, 4]]  # 3 (0.0064) is dropped
    assert conf[0].tolist() == approx([0.30 / total, 0.06 / total, 0.0096 / total])
    assert conf[0].tolist() == approx([0.797194, 0.159439, 0.025510], rel=1e-4)


def test_fuse_bayes_two_missing_classes_share_the_residual_geometrically():
    c1 = np.array([[1, 2, 3]])
    f1 = np.array([[0.4, 0.3, 0.2]])  # o1 = 0.1
    c2 = np.array([[5, 6, 1]])
    f2 = np.array([[0.55, 0.25, 0.1]])  # o2 = 0.1
    cls, conf = fu.fuse_bayes(c1, f1, c2, f2)
    # s1 walk: 1 -> 0.1 (found); 2 missing -> 0.8*0.1 = 0.08, o2 = 0.02;
    #          3 missing -> 0.8*0.02 = 0.016, o2 = 0.004
    # s2 walk: 5 new -> 0.8*0.1 = 0.08, o1 = 0.02; 6 new -> 0.016, o1 = 0.004
    # products: 1: 0.04, 2: 0.024, 3: 0.0032, 5: 0.044, 6: 0.004, others 0.000016
    total = 0.04 + 0.024 + 0.0032 + 0.044 + 0.004 + 0.000016
    assert cls.tolist() == [[5, 1, 2]]
    assert conf[0].tolist() == approx([0.044 / total, 0.04 / total, 0.024 / total])


def test_fuse_bayes_floors_and_copies():
    # s1 all mass on its classes: o1 = 0 -> floored at 0.001
    c1 = np.array([[1, 2, 3], [-1, -1, -1]])
    f1 = np.array([[0.7, 0.2, 0.1], [0, 0, 0]])
    c2 = np.array([[1, 2, 3], [4, 5, 6]])
    f2 = np.array([[0.5, 0.3, 0.2], [0.5, 0.3, 0.1]])
    cls, conf = fu.fuse_bayes(c1, f1, c2, f2)
    # row 0: products 0.35, 0.06, 0.02, others 0.001*0.001 = 1e-6
    total = 0.35 + 0.06 + 0.02 + 1e-6
    assert cls[0].tolist() == [1, 2, 3]
    assert conf[0].tolist() == approx([0.35 / total, 0.06 / total, 0.02 / total])
    # row 1: empty voxel takes the observation unchanged
    assert cls[1].tolist() == [4, 5, 6]
    assert conf[1].tolist() == approx([0.5, 0.3, 0.1])


def ref_fuse_bayes(c1, f1, c2, f2):
    """semantic_slam's SemanticsBayesian::semanticFusion, transcribed voxel by voxel."""
    s1 = [(c, f) for c, f in zip(c1, f1, strict=True) if c >= 0]
    s2 = [(c, f) for c, f in zip(c2, f2, strict=True) if c >= 0]
    if not s1:
        return list(c2), list(f2)
    if not s2:
        return list(c1), list(f1)
    o1 = max(1.0 - sum(f for _, f in s1), 0.001)
    o2 = max(1.0 - sum(f for _, f in s2), 0.001)
    colors = [[c, f] for c, f in s1]
    conf2 = []
    d2 = dict(s2)
    for c, _ in s1:
        if c in d2:
            conf2.append(d2[c])
        else:
            conf2.append(0.8 * o2)
            o2 -= 0.8 * o2
    names1 = [c for c, _ in s1]
    for c, f in s2:
        if c not in names1:
            colors.append([c, 0.8 * o1])
            o1 -= 0.8 * o1
            conf2.append(f)
    total = o1 * o2
    for i in range(len(colors)):
        colors[i][1] *= conf2[i]
        total += colors[i][1]
    for i in range(len(colors)):
        colors[i][1] = max(colors[i][1] / total, 0.001)
    colors.sort(key=lambda x: -x[1])
    colors = colors[:3] + [[-1, 0.0]] * (3 - len(colors[:3]))
    return [c for c, _ in colors], [f for _, f in colors]


def test_fuse_bayes_matches_reference_on_random_states():
    rng = np.random.default_rng(0)
    m = 400

    def random_sets():
        cls = np.full((m, 3), -1, np.int64)
        conf = np.zeros((m, 3))
        for i in range(m):
            n = 0 if rng.random() < 0.05 else 3
            cls[i, :n] = rng.choice(6, size=n, replace=False)
            d = rng.dirichlet(np.ones(4) * 0.7)
            if rng.random() < 0.2:
                d = np.append(rng.dirichlet(np.ones(3)), 0.0)  # residual 0 -> eps floor
            conf[i, :n] = np.sort(d[:3])[::-1][:n]
        return cls, conf.astype(np.float32)

    c1, f1 = random_sets()
    c2, f2 = random_sets()
    cls, conf = fu.fuse_bayes(c1, f1, c2, f2)
    for i in range(m):
        rc, rf = ref_fuse_bayes(c1[i].tolist(), f1[i].astype(float).tolist(), c2[i].tolist(),
                                f2[i].astype(float).tolist())
        assert cls[i].tolist() == rc, i
        assert conf[i].tolist() == approx(rf), i


def test_fuse_max_matches_reference_on_random_states():
    rng = np.random.default_rng(1)
    m = 300
    c1, c2 = rng.integers(-1, 4, m), rng.integers(-1, 4, m)
    p1 = rng.choice([0.2, 0.5, 0.7, 0.9], m).astype(np.float32)
    p2 = rng.choice([0.2, 0.5, 0.7, 0.9], m).astype(np.float32)
    cls, conf = fu.fuse_max(c1, p1, c2, p2)
    for i in range(m):
        a, b, pa, pb = int(c1[i]), int(c2[i]), float(p1[i]), float(p2[i])
        if a < 0:
            want = (b, pb)
        elif b < 0:
            want = (a, pa)
        elif a == b:
            want = (a, (pa + pb) / 2)
        else:
            want = (a, pa * 0.9) if pa > pb else (b, pb * 0.9)
        assert (int(cls[i]), float(conf[i])) == (want[0], approx(want[1]))


