"""multiclass-bayes (generator): an inner node's semantics are Algorithm 1 over its own children,
however many distinct class colours the tree holds (averaged colours make tens of thousands)."""

from __future__ import annotations

import numpy as np

from evsmap.mapping.fusion import MCBState
from evsmap.mapping.generator import WHITE
from evsmap.mapping.keys import pack
from evsmap.registry import UPDATERS
from evsmap.updaters import mcb_generator as gen

DISTINCT = 70_000
"""Above 65,536: no 16-bit numbering of the colours can hold them."""


def _records(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` node records, each with 1-3 distinct class colours drawn from 2**24 values."""
    rec = np.zeros(n, dtype=gen.RECORD)
    colours = rng.choice(1 << 24, size=(n, 3), replace=False).astype(np.uint32)
    slots = rng.integers(1, 4, size=n)
    colours[np.arange(3)[None, :] >= slots[:, None]] = WHITE
    rec["colors"] = colours
    rec["logodds"] = np.sort(rng.uniform(-3, 3, size=(n, 3)).astype(np.float32), axis=1)[:, ::-1]
    rec["logodds"][colours == WHITE] = gen.LOGINIT
    rec["others"] = rng.uniform(-5, 0, size=n).astype(np.float32)
    rec["rgb"] = rng.integers(0, 255, size=(n, 3), dtype=np.uint8)
    return rec


def _inner_in_chunks(updater, child, group, n_groups, chunk=4000):
    """The same inner records computed a few thousand parents at a time (so few colours at once
    that any numbering of them is exact): the reference."""
    out = np.zeros(n_groups, dtype=gen.RECORD)
    for start in range(0, n_groups, chunk):
        sel = (group >= start) & (group < start + chunk)
        stop = min(start + chunk, n_groups)
        out[start:stop] = updater.inner_payload(child[sel], group[sel] - start, stop - start)
    return out


def test_state_keeps_class_ids_above_16_bits():
    ids = np.array([[70_000, 40_000, -1]], dtype=np.int64)
    state = MCBState(ids, np.zeros((1, 3)), np.zeros(1))
    assert state.classes.tolist() == [[70_000, 40_000, -1]]


def test_state_refuses_ids_it_cannot_hold():
    ids = np.array([[1 << 40, -1, -1]], dtype=np.int64)
    try:
        MCBState(ids, np.zeros((1, 3)), np.zeros(1))
    except ValueError as exc:
        assert "class ids" in str(exc)
    else:
        raise AssertionError("a 41-bit class id was accepted")


def test_inner_nodes_over_65536_distinct_colours_equal_their_own_childrens_merge():
    rng = np.random.default_rng(7)
    n_groups = DISTINCT // 2
    child = _records(2 * n_groups, rng)
    group = np.repeat(np.arange(n_groups), 2)
    assert len(np.unique(child["colors"][child["colors"] != WHITE])) > 65_536
    updater = UPDATERS.create("multiclass-bayes")
    whole = updater.inner_payload(child, group, n_groups)
    reference = _inner_in_chunks(updater, child, group, n_groups)
    assert np.array_equal(whole["colors"], reference["colors"])
    assert np.array_equal(whole["logodds"].view(np.uint32), reference["logodds"].view(np.uint32))
    assert np.array_equal(whole["others"].view(np.uint32), reference["others"].view(np.uint32))
    # and no merged colour is one no child had
    assert np.isin(whole["colors"][whole["colors"] != WHITE], child["colors"]).all()


def test_every_inner_node_of_a_map_with_over_65536_colours_is_algorithm1_of_its_children():
    rng = np.random.default_rng(11)
    updater = UPDATERS.create("multiclass-bayes")
    # pairs of occupied leaves in distinct parents, spread over a few upper-level nodes
    n = DISTINCT
    base = rng.choice(64 ** 3, size=n // 2, replace=False)
    keys = np.stack([32768 + 2 * (base % 64), 32768 + 2 * ((base // 64) % 64),
                     32768 + 2 * (base // 4096)], axis=1)
    keys = np.concatenate([keys, keys + [1, 0, 0]])
    codes = np.unique(pack(keys.astype(np.int64)))
    m = updater.map
    index, _ = m.insert_leaves(codes)
    rec = _records(len(codes), rng)
    m.payload("sem_colors")[index] = rec["colors"]
    m.payload("class_logodds")[index] = rec["logodds"]
    m.payload("others")[index] = rec["others"]
    m.payload("rgb")[index] = rec["rgb"]
    m.logodds_for_writing()[index] = 1.0
    tree = updater.tree()
    pay = tree.payload
    parents = tree.parents()
    inner = np.flatnonzero(tree.child_mask != 0)
    kids = np.flatnonzero(np.isin(parents, inner))
    kids = kids[np.lexsort((kids, parents[kids]))]  # by parent, child order within
    owners, group = np.unique(parents[kids], return_inverse=True)
    assert len(np.unique(pay["colors"][kids][pay["colors"][kids] != WHITE])) > 65_536
    reference = _inner_in_chunks(updater, pay[kids], group, len(owners))
    assert np.array_equal(pay["colors"][owners], reference["colors"])
    assert np.array_equal(pay["logodds"][owners].view(np.uint32),
                          reference["logodds"].view(np.uint32))
    assert np.array_equal(pay["others"][owners].view(np.uint32),
                          reference["others"].view(np.uint32))
