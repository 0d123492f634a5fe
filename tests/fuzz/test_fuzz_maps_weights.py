"""Fuzz targets: evsmap's own binary files a user can hand it - OctoMap ``.ot`` / ``.bt`` maps
(:mod:`evsmap.mapping.octree_io`, the multiclass-bayes loader) and weights files (state dicts,
training checkpoints, weight cards, ``evsmap weights``).

Every sample is written by evsmap's own writers first (a small semantic map, a tiny network's
state dict with its card, a FEAGNet-V1 state dict), then mutated byte-wise and format-aware
(headers with NaN / Inf / 0 / negative resolutions, sizes claiming 10^12 nodes, looping child
masks, legacy and zip pickles, pickles that call a function, NaN tensors, cards with wrong
fields). The property is :func:`tests.fuzz.harness.check_file`'s: one line naming the file, no
traceback, no hang, bounded memory.
"""

from __future__ import annotations

import io
import os
import pickle
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st
from torch import nn

from evsmap.errors import DataFormatError
from evsmap.mapping.keys import KEY_OFFSET, pack
from evsmap.mapping.octree_io import (
    bt_bytes,
    ot_bytes,
    parse_bt,
    parse_ot,
    read_bt,
    read_ot,
)
from evsmap.mapping.tree import build_color_tree, build_tree
from tests.fuzz.harness import check_cli, check_file, mutated_bytes, text_lines, write_variant

RES = 0.05


# ------------------------------------------------------------------------------ octree samples
def _leaves(n: int = 60, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    xyz = KEY_OFFSET + rng.integers(-20, 20, (n, 3))
    xyz = np.unique(xyz, axis=0)
    codes = np.sort(pack(xyz))
    values = rng.uniform(-2, 2, len(codes)).astype(np.float32)
    return codes, values


@pytest.fixture(scope="module")
def octree_samples() -> dict[str, bytes]:
    from evsmap.updaters.multiclass_bayes import PAYLOAD_FORMAT, TREE_ID

    codes, values = _leaves()
    plain = build_tree(codes, values)
    colour = build_color_tree(codes, values,
                              np.random.default_rng(1).integers(0, 255, (len(codes), 3)))
    pay = np.zeros(len(codes), dtype=PAYLOAD_FORMAT)
    pay["classes"][:, 0] = np.arange(len(codes)) % 40
    pay["classes"][:, 1:] = 255
    pay["logodds"][:, 0] = 1.5
    mcb = build_tree(codes, values, payload=pay)
    return {"ot": ot_bytes(plain, RES), "color": ot_bytes(colour, RES, tree_id="ColorOcTree"),
            "mcb": ot_bytes(mcb, RES, tree_id=TREE_ID, payload_format=PAYLOAD_FORMAT),
            "bt": bt_bytes(plain, RES)}


def _split_header(data: bytes) -> tuple[list[str], bytes]:
    at = data.index(b"\ndata\n") + len(b"\ndata\n")
    return data[:at].decode("ascii").splitlines(), data[at:]


_RES = st.sampled_from(["nan", "NaN", "inf", "-inf", "0", "-0", "-0.05", "1e-320", "1e308",
                        "1e400", "0x1p-3", "", "0.05abc", "5e-2"])
_SIZE = st.one_of(st.sampled_from(["0", "1", "-1", "10" + "0" * 11, "99999999999999999999",
                                   "1e3", "", "0x10", "2" * 40]),
                  st.integers(0, 2**64).map(str))


@st.composite
def header_edits(draw: st.DrawFn, data: bytes) -> bytes:
    """A format-aware edit: the id, size or res line replaced, duplicated or removed, the body
    truncated, cut or given trailing bytes; then maybe a byte mutation on top."""
    head, body = _split_header(data)
    lines = list(head)
    for _ in range(draw(st.integers(1, 3))):
        what = draw(st.sampled_from(["res", "size", "id", "drop", "body", "tail", "magic"]))
        if what == "res":
            lines = [f"res {draw(_RES)}" if ln.startswith("res") else ln for ln in lines]
        elif what == "size":
            lines = [f"size {draw(_SIZE)}" if ln.startswith("size") else ln for ln in lines]
        elif what == "id":
            new = draw(st.sampled_from(["1", "OcTree", "ColorOcTree", "MultiClassBayesOcTree",
                                        "", "Nope", "#x", "OcTree extra"]))
            lines = [f"id {new}" if ln.startswith("id") else ln for ln in lines]
        elif what == "drop":
            key = draw(st.sampled_from(["id", "size", "res", "data"]))
            lines = [ln for ln in lines if not ln.startswith(key)]
        elif what == "body":
            cut = draw(st.integers(0, len(body)))
            body = body[:cut]
        elif what == "tail":
            body = body + draw(st.binary(min_size=1, max_size=40))
        elif what == "magic":
            lines[0] = draw(st.sampled_from(["# Octomap OcTree file", "", "# octomap", "#",
                                             "# Octomap OcTree binary file"]))
    out = ("\n".join(lines) + "\n").encode("ascii") + body
    if draw(st.booleans()):
        out = draw(mutated_bytes(out, max_ops=2))
    return out


def _looping_ot(size: int, mask: int, value: float = 0.0, extra: bytes = b"") -> bytes:
    """An ``.ot`` whose every node has child mask ``mask`` (a tree deeper than 16 levels when
    ``mask`` is non-zero), ``size`` records."""
    rec = np.zeros(size, dtype=[("value", "<f4"), ("mask", "u1")])
    rec["value"] = value
    rec["mask"] = mask
    return (b"# Octomap OcTree file\nid OcTree\nsize " + str(size).encode() + b"\nres 0.05\n"
            b"data\n" + rec.tobytes() + extra)


@st.composite
def structural_ot(draw: st.DrawFn) -> bytes:
    """Generated from scratch: a chain of single-child masks (depth up to 40), full masks,
    random masks, NaN / Inf values, sizes that lie."""
    kind = draw(st.sampled_from(["chain", "random", "full"]))
    n = draw(st.integers(1, 60))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    rec = np.zeros(n, dtype=[("value", "<f4"), ("mask", "u1")])
    if kind == "chain":
        rec["mask"] = 1 << draw(st.integers(0, 7))
        rec["mask"][-1] = 0
    elif kind == "full":
        rec["mask"] = 255
    else:
        rec["mask"] = rng.integers(0, 256, n)
    rec["value"] = draw(st.sampled_from([np.nan, np.inf, -np.inf, 0.0, 1e38]))
    size = draw(st.one_of(st.just(n), st.integers(0, 2 * n), st.just(10**12)))
    return (b"# Octomap OcTree file\nid OcTree\nsize " + str(size).encode() + b"\nres 0.05\n"
            b"data\n" + rec.tobytes())


@st.composite
def structural_bt(draw: st.DrawFn) -> bytes:
    """``.bt`` bodies from scratch: random 2-byte records (inner-node chains deeper than 16,
    empty inner nodes), any size."""
    n = draw(st.integers(1, 40))
    body = draw(st.one_of(st.binary(min_size=2 * n, max_size=2 * n),
                          st.just(b"\xff\xff" * n), st.just(b"\x03\x00" * n)))
    size = draw(st.one_of(st.integers(0, 400), st.just(10**12)))
    return (b"# Octomap OcTree binary file\nid OcTree\nsize " + str(size).encode()
            + b"\nres 0.05\ndata\n" + body)


def _read_any(path: Path):
    if path.suffix == ".bt":
        return read_bt(path)
    return read_ot(path)


def test_fuzz_octree_ot_bytes(tmp_path_factory, octree_samples):
    folder = tmp_path_factory.mktemp("ot")

    @given(st.sampled_from(["ot", "color", "mcb"]).flatmap(
        lambda k: mutated_bytes(octree_samples[k])))
    def inner(data):
        path = write_variant(folder / "map.ot", data)
        check_file("octree/ot-bytes", lambda: read_ot(path), path)

    inner()


def test_fuzz_octree_ot_header(tmp_path_factory, octree_samples):
    folder = tmp_path_factory.mktemp("oth")

    @given(st.sampled_from(["ot", "color", "mcb"]).flatmap(
        lambda k: header_edits(octree_samples[k])))
    def inner(data):
        path = write_variant(folder / "map.ot", data)
        check_file("octree/ot-header", lambda: read_ot(path), path)

    inner()


def test_fuzz_octree_ot_structure(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ots")

    @given(structural_ot())
    def inner(data):
        path = write_variant(folder / "gen.ot", data)
        check_file("octree/ot-structure", lambda: read_ot(path), path)

    inner()


def test_fuzz_octree_bt(tmp_path_factory, octree_samples):
    folder = tmp_path_factory.mktemp("bt")

    @given(st.one_of(mutated_bytes(octree_samples["bt"]), header_edits(octree_samples["bt"]),
                     structural_bt()))
    def inner(data):
        path = write_variant(folder / "map.bt", data)
        check_file("octree/bt", lambda: read_bt(path), path)

    inner()


def test_octree_refuses_huge_and_looping_claims(tmp_path):
    """The sizes and shapes the mutators rarely hit: 10^12 nodes claimed, an endless chain."""
    cases = {
        "huge.ot": _looping_ot(4, 1).replace(b"size 4", b"size 1000000000000"),
        "chain.ot": _looping_ot(40, 1),
        "chain-tail.ot": _looping_ot(40, 1, extra=b"\0" * 5),
        "full.ot": _looping_ot(300, 255),
        "huge.bt": b"# Octomap OcTree binary file\nid OcTree\nsize 1000000000000\nres 0.1\n"
                   b"data\n" + b"\xff\xff" * 30,
        "deep.bt": b"# Octomap OcTree binary file\nid OcTree\nsize 41\nres 0.1\ndata\n"
                   + b"\x03\x00" * 40 + b"\x00\x00",
    }
    for name, data in cases.items():
        path = write_variant(tmp_path / name, data)
        check_file("octree/claims", lambda p=path: _read_any(p), path)
    from evsmap.updaters.multiclass_bayes import PAYLOAD_FORMAT, TREE_ID, load_multiclass_bayes

    root = np.zeros(1, dtype=[("value", "<f4"), ("payload", PAYLOAD_FORMAT), ("mask", "u1")])
    head = b"# Octomap OcTree file\nid " + TREE_ID.encode() + b"\nsize 1\nres 0.05\ndata\n"
    path = write_variant(tmp_path / "root-leaf.ot", head + root.tobytes())
    check_file("octree/claims", lambda: load_multiclass_bayes(path), path)
    # 10 records (a chain to depth 7, two leaves at depth 8): 3.4e7 finest voxels to restore
    masks = [1] * 7 + [3, 0, 0]
    chain = np.zeros(len(masks), dtype=root.dtype)
    chain["mask"] = masks
    head = head.replace(b"size 1", b"size 10")
    path = write_variant(tmp_path / "coarse-leaves.ot", head + chain.tobytes())
    check_file("octree/claims", lambda: load_multiclass_bayes(path), path)
    for data in (_looping_ot(3, 0),):
        check_file("octree/claims", lambda d=data: parse_ot(d, name="bytes.ot"), None,
                   names=("bytes.ot",))
        check_file("octree/claims", lambda d=data: parse_bt(d, name="bytes.bt"), None,
                   names=("bytes.bt",))


def test_fuzz_multiclass_bayes_loader(tmp_path_factory, octree_samples):
    from evsmap.updaters.multiclass_bayes import load_multiclass_bayes

    folder = tmp_path_factory.mktemp("mcb")

    @given(st.one_of(mutated_bytes(octree_samples["mcb"]), header_edits(octree_samples["mcb"])))
    def inner(data):
        path = write_variant(folder / "semantic.ot", data)
        check_file("octree/multiclass-bayes-load", lambda: load_multiclass_bayes(path), path)

    inner()


def test_fuzz_updater_restore(tmp_path_factory, octree_samples):
    """``restore`` of another updater (orgb: a ColorOcTree at 0.05 m) on mutated colour maps."""
    from evsmap.registry import UPDATERS

    folder = tmp_path_factory.mktemp("restore")
    updater = UPDATERS.create("orgb", resolution=RES)

    @given(st.one_of(mutated_bytes(octree_samples["color"]),
                     header_edits(octree_samples["color"])))
    def inner(data):
        path = write_variant(folder / "colour.ot", data)
        check_file("octree/orgb-restore", lambda: updater.restore(path), path)

    inner()
    root = np.zeros(1, dtype=[("value", "<f4"), ("rgb", "u1", (3,)), ("mask", "u1")])
    path = write_variant(folder / "root.ot", b"# Octomap OcTree file\nid ColorOcTree\nsize 1\n"
                         b"res 0.05\ndata\n" + root.tobytes())
    check_file("octree/orgb-restore", lambda: updater.restore(path), path)


# ------------------------------------------------------------------------------ weights samples
class _Tiny(nn.Module):
    """A network with an encoder (for ``--init``) and a classifier."""

    def __init__(self) -> None:
        super().__init__()
        self.encoder = nn.Sequential(nn.Conv2d(3, 4, 3), nn.BatchNorm2d(4))
        self.head = nn.Conv2d(4, 2, 1)


def _tiny_state() -> dict[str, torch.Tensor]:
    torch.manual_seed(0)
    return {k: v.clone() for k, v in _Tiny().state_dict().items()}


def _saved(obj, *, legacy: bool = False) -> bytes:
    buf = io.BytesIO()
    torch.save(obj, buf, _use_new_zipfile_serialization=not legacy)
    return buf.getvalue()


def _checkpoint(state: dict[str, torch.Tensor], card: dict) -> dict:
    """What ``evsmap train`` writes after an epoch (:mod:`evsmap.train.checkpoint`)."""
    from evsmap.train.checkpoint import FORMAT, VERSION, rng_state
    from evsmap.train.recipe import load_recipe

    module = _Tiny()
    optimizer = torch.optim.SGD(module.parameters(), lr=0.1, momentum=0.9)
    return {"format": FORMAT, "version": VERSION, "state_dict": state, "card": card,
            "optimizer": optimizer.state_dict(), "scheduler": {"last_epoch": 3}, "scaler": None,
            "rng": rng_state(), "epoch": 3, "recipe": load_recipe("synth-proxy").as_dict(),
            "run": {"model": "tiny", "options": {}, "world_size": 1},
            "history": [{"epoch": 1, "loss": 0.5}], "best": {"epoch": 2, "miou": 0.25},
            "best_iou": np.float64(0.25)}


@pytest.fixture(scope="module")
def weights_samples(tmp_path_factory) -> dict[str, bytes]:
    from evsmap.segmenters.cards import make_card

    state = _tiny_state()
    card = make_card(model="tiny", options={"dataset": "nyuv2"}, num_classes=2,
                     class_names=["a", "b"], state_dict=state, val_miou=0.5)
    checkpoint = _checkpoint(state, card)
    return {"carded": _saved({"state_dict": state, "card": card}),
            "plain": _saved(state),
            "legacy": _saved({"state_dict": state, "card": card}, legacy=True),
            "checkpoint": _saved(checkpoint),
            "module": _saved({f"module.{k}": v for k, v in state.items()})}


def _read_and_load(path: Path):
    from evsmap.segmenters.weights import load_weights

    return load_weights(_Tiny(), path)


def test_fuzz_weights_load(tmp_path_factory, weights_samples):
    folder = tmp_path_factory.mktemp("w")

    @given(st.sampled_from(sorted(weights_samples)).flatmap(
        lambda k: mutated_bytes(weights_samples[k])))
    def inner(data):
        path = write_variant(folder / "weights.pt", data)
        check_file("weights/load", lambda: _read_and_load(path), path)

    inner()


def test_fuzz_weights_zip_members(tmp_path_factory, weights_samples):
    """Zip-aware edits: one member of the archive (the pickle, a tensor's storage, the version
    record) mutated, dropped or truncated, the archive rebuilt around it."""
    folder = tmp_path_factory.mktemp("wz")
    with zipfile.ZipFile(io.BytesIO(weights_samples["carded"])) as z:
        members = {i.filename: z.read(i) for i in z.infolist()}
    names = sorted(members)

    @given(st.sampled_from(names), st.sampled_from(["mutate", "drop", "empty"]), st.data())
    def inner(member, how, data):
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as z:
            for name in names:
                body = members[name]
                if name == member:
                    if how == "drop":
                        continue
                    body = b"" if how == "empty" else data.draw(mutated_bytes(body))
                z.writestr(name, body)
        path = write_variant(folder / "zipped.pt", buf.getvalue())
        check_file("weights/zip-members", lambda: _read_and_load(path), path)

    inner()


def test_fuzz_training_checkpoint(tmp_path_factory, weights_samples):
    from evsmap.train.checkpoint import load_checkpoint

    folder = tmp_path_factory.mktemp("ck")

    @given(mutated_bytes(weights_samples["checkpoint"]))
    def inner(data):
        path = write_variant(folder / "checkpoint.pt", data)
        check_file("weights/checkpoint", lambda: load_checkpoint(path), path)

    inner()


@st.composite
def generated_checkpoint(draw: st.DrawFn, real: dict) -> dict:
    """A real checkpoint's fields (and its generator states' fields) replaced or dropped."""
    obj = dict(real)
    obj["rng"] = dict(obj["rng"])
    obj["rng"]["numpy"] = dict(obj["rng"]["numpy"])
    obj["run"] = dict(obj["run"])
    tables = [obj, obj["rng"], obj["rng"]["numpy"], obj["run"]]
    for _ in range(draw(st.integers(1, 3))):
        where = draw(st.sampled_from(tables))
        if not where:
            continue
        key = draw(st.sampled_from(sorted(where)))
        if draw(st.booleans()):
            where.pop(key)
        else:
            where[key] = draw(st.one_of(_CARD_VALUE, _tensor(),
                                        st.lists(st.integers(-1, 2**33), max_size=700)))
    return obj


def test_fuzz_checkpoint_generated(tmp_path_factory):
    from evsmap.segmenters.cards import make_card
    from evsmap.train.checkpoint import load_checkpoint

    folder = tmp_path_factory.mktemp("ckg")
    state = _tiny_state()
    real = _checkpoint(state, make_card(model="tiny", options={}, num_classes=2,
                                        class_names=["a", "b"], state_dict=state))
    path = folder / "checkpoint.pt"
    path.write_bytes(_saved(real))
    assert load_checkpoint(path)["epoch"] == 3

    @given(generated_checkpoint(real))
    def inner(obj):
        path.write_bytes(_saved(obj))
        check_file("weights/checkpoint-generated", lambda: load_checkpoint(path), path)

    inner()


def test_fuzz_encoder_init(tmp_path_factory, weights_samples):
    from evsmap.train.init import load_encoder_weights

    folder = tmp_path_factory.mktemp("init")

    @given(st.sampled_from(["carded", "plain", "legacy"]).flatmap(
        lambda k: mutated_bytes(weights_samples[k])))
    def inner(data):
        path = write_variant(folder / "encoder.pt", data)
        check_file("weights/init", lambda: load_encoder_weights(_Tiny(), path), path)

    inner()


# generated objects: what a user's torch.save could hold
_SCALAR = st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70),
                    st.sampled_from([10**400, -(10**400)]),
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12))
_KEY = st.one_of(st.text(max_size=6), st.integers(-3, 3), st.tuples(st.integers(0, 2)))
_CARD_VALUE = st.recursive(_SCALAR, lambda inner: st.one_of(
    st.lists(inner, max_size=3), st.dictionaries(_KEY, inner, max_size=3)),
    max_leaves=8)
_CARD_KEYS = ["card_version", "model", "options", "num_classes", "class_names",
              "evsmap_version", "git_commit", "tensors", "tensors_sha256", "val_miou",
              "test_miou", "metrics", "reader", "dataset", "format", "version"]


@st.composite
def _tensor(draw: st.DrawFn) -> torch.Tensor:
    dtype = draw(st.sampled_from([torch.float32, torch.float64, torch.float16, torch.int64,
                                  torch.uint8, torch.bool, torch.bfloat16, torch.complex64]))
    shape = draw(st.lists(st.integers(0, 4), max_size=4))
    fill = draw(st.sampled_from([0.0, 1.0, float("nan"), float("inf")]))
    t = torch.zeros(shape, dtype=torch.float64).fill_(fill)
    try:
        return t.to(dtype)
    except RuntimeError:
        return torch.zeros(shape, dtype=dtype)


@st.composite
def generated_weights(draw: st.DrawFn) -> object:
    state = _tiny_state()
    kind = draw(st.sampled_from(["state", "wrapped", "card", "toplevel", "checkpoint"]))
    if kind == "toplevel":
        return draw(st.one_of(_CARD_VALUE, st.builds(lambda: [state]),
                              st.builds(lambda: tuple(state.values())), _tensor()))
    for _ in range(draw(st.integers(0, 3))):  # wrong shapes / dtypes / values / keys
        key = draw(st.sampled_from([*_tiny_state(), "extra.weight", "", "module.x", 1, (1, 2)]))
        state[key] = draw(_tensor())
    if draw(st.booleans()) and state:
        state.pop(draw(st.sampled_from(list(state))))
    if kind == "state":
        return state
    card = {k: draw(_CARD_VALUE) for k in draw(st.lists(st.sampled_from(_CARD_KEYS),
                                                         max_size=8, unique=True))}
    if draw(st.booleans()):
        card["model"] = draw(st.sampled_from(["tiny", "feagnet-v1", "nope"]))
    out: dict = {"state_dict": state}
    if kind in ("card", "checkpoint"):
        out["card"] = draw(st.one_of(st.just(card), _CARD_VALUE))
    if kind == "checkpoint":
        out.update(format=draw(st.sampled_from(["evsmap-train-checkpoint", "x", 1])),
                   version=draw(st.sampled_from([1, 2, "1", None])), epoch=draw(_SCALAR))
    return out


def test_fuzz_weights_generated(tmp_path_factory, capsys):
    from evsmap.train.checkpoint import load_checkpoint

    folder = tmp_path_factory.mktemp("wg")

    @given(generated_weights(), st.booleans())
    def inner(obj, legacy):
        path = folder / "gen.pt"
        path.write_bytes(_saved(obj, legacy=legacy))
        check_file("weights/generated", lambda: _read_and_load(path), path)
        check_file("weights/generated", lambda: load_checkpoint(path), path)
        check_cli("weights/generated-cli", ["weights", "show", str(path)], (path.name,), capsys)
        check_cli("weights/generated-cli", ["weights", "list", str(path), "--json"],
                  (path.name,), capsys)

    inner()


def test_fuzz_weights_cli(tmp_path_factory, weights_samples, capsys):
    folder = tmp_path_factory.mktemp("wcli")

    @given(st.sampled_from(sorted(weights_samples)).flatmap(
        lambda k: mutated_bytes(weights_samples[k])),
        st.sampled_from(["show", "show-json", "list", "list-json", "convert"]))
    def inner(data, how):
        path = write_variant(folder / "cli.pt", data)
        action, _, json_ = how.partition("-")
        argv = ["weights", action, str(path)] + (["--json"] if json_ else [])
        if action == "convert":
            argv += ["--out", str(folder / "out.pt"), "--force"]
        if action == "show":  # exit 1 is show's answer to tensors that differ from the card
            check_file("weights/cli", lambda: _show(argv, path.name, capsys), path)
        else:
            check_cli("weights/cli", argv, (path.name,), capsys)

    inner()


def _show(argv: list[str], name: str, capsys) -> None:
    """``evsmap weights show``: exit 0, 1 with the verification saying the tensors differ, or
    2 with one line naming the file."""
    from evsmap.cli.main import main

    capsys.readouterr()
    code = main(argv)
    out, err = capsys.readouterr()
    if code == 1:
        assert "differ" in out and not err.strip(), (out[-300:], err)
    elif code != 0:
        lines = [ln for ln in err.splitlines() if not ln.startswith("evsmap: warning:")]
        assert code == 2 and len(lines) == 1 and name in lines[0], (code, err)


# pickles that call a function: refused, never run
class _Boom:
    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


class _EvalBoom:
    def __init__(self, marker: str) -> None:
        self.marker = marker

    def __reduce__(self):
        return (eval, (f"open({self.marker!r}, 'w').close()",))


def _with_pickle(sample: bytes, card_value: bytes, prefix: bytes = b"") -> bytes:
    """The zip weights file ``sample`` with its pickle replaced by one of
    ``{"state_dict": {}, "card": {"a": <card_value opcodes>}}`` (``prefix``: opcodes run
    before, whose objects stay below on the stack)."""
    with zipfile.ZipFile(io.BytesIO(sample)) as z:
        members = {i.filename: z.read(i) for i in z.infolist()}

    def text(s: str) -> bytes:
        return b"X" + len(s).to_bytes(4, "little") + s.encode()

    pkl = next(n for n in members if n.endswith("data.pkl"))
    members[pkl] = (b"\x80\x02" + prefix + b"}(" + text("state_dict") + b"}" + text("card")
                    + b"}" + text("a") + card_value + b"su.")
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as z:
        for name, body in members.items():
            z.writestr(name, body)
    return out.getvalue()


def test_weights_nesting_cycles_and_shared_containers(tmp_path, weights_samples, capsys):
    """Pickles a few bytes long that every walk over the object chokes on: lists nested 10^5
    deep (RecursionError in repr, the card printer, JSON), a list holding itself, and 60 levels
    of lists sharing their child twice (2^60 items for a walk)."""
    deep = b"]" * 100_000 + b"a" * 99_999
    cyclic = b"]q\x00h\x00a"
    shared = b"]q\x00" + b"".join(b"](h" + bytes([i - 1]) + b"h" + bytes([i - 1]) + b"eq"
                                   + bytes([i]) for i in range(1, 61))
    for name, opcodes, prefix in (("deep", deep, b""), ("cyclic", cyclic, b""),
                                  ("shared", b"h\x3c", shared)):
        path = write_variant(tmp_path / f"{name}.pt", _with_pickle(weights_samples["plain"],
                                                                  opcodes, prefix))
        check_file("weights/nesting", lambda p=path: _read_and_load(p), path)
        for argv in (["weights", "show", str(path)], ["weights", "show", str(path), "--json"],
                     ["weights", "list", str(path), "--json"]):
            check_cli("weights/nesting", argv, (path.name,), capsys)
        with pytest.raises(DataFormatError, match="it holds"):
            _read_and_load(path)


def test_pickled_code_is_refused_and_not_run(tmp_path, capsys):
    from evsmap.segmenters.cards import inspect_weights
    from evsmap.train.checkpoint import load_checkpoint
    from evsmap.train.init import load_encoder_weights

    state = _tiny_state()
    n = 0
    for cls in (_Boom, _EvalBoom):
        for legacy in (False, True):
            for wrap in ("bare", "card", "tensor"):
                marker = tmp_path / f"ran-{n}"
                boom = cls(str(marker))
                obj = {"bare": boom, "card": {"state_dict": state, "card": {"model": boom}},
                       "tensor": {"state_dict": {**state, "x": boom}}}[wrap]
                path = tmp_path / f"evil-{n}.pt"
                path.write_bytes(_saved(obj, legacy=legacy))
                n += 1
                for call in (lambda p=path: _read_and_load(p),
                             lambda p=path: load_checkpoint(p),
                             lambda p=path: load_encoder_weights(_Tiny(), p),
                             lambda p=path: inspect_weights(p)):
                    check_file("weights/pickle-exec", call, path)
                for argv in (["weights", "show", str(path)], ["weights", "list", str(path)]):
                    check_cli("weights/pickle-exec", argv, (path.name,), capsys)
                assert not marker.exists(), f"{path}: the pickled call ran"
                refused = inspect_weights(path)
                assert refused.error is not None and "may not hold" in refused.error
    # a plain pickle (not torch's format) holding the call
    marker = tmp_path / "ran-plain"
    path = tmp_path / "plain-pickle.pt"
    path.write_bytes(pickle.dumps(_Boom(str(marker))))
    check_file("weights/pickle-exec", lambda: _read_and_load(path), path)
    assert not marker.exists()


@pytest.fixture(scope="module")
def feagnet_v1_bytes() -> bytes:
    from evsmap.registry import SEGMENTERS

    seg = SEGMENTERS.create("feagnet-v1")
    return _saved({k: v.clone() for k, v in seg.module.state_dict().items()})


def test_fuzz_feagnet_v1_state(tmp_path_factory, feagnet_v1_bytes):
    """A real network's state dict (zip format), mutated, loaded into FEAGNet-V1."""
    from evsmap.registry import SEGMENTERS
    from evsmap.segmenters.weights import load_weights

    module = SEGMENTERS.create("feagnet-v1").module
    folder = tmp_path_factory.mktemp("fv1")

    @given(mutated_bytes(feagnet_v1_bytes, max_ops=2))
    def inner(data):
        path = write_variant(folder / "feagnet-v1.pt", data)
        check_file("weights/feagnet-v1", lambda: load_weights(module, path), path)

    inner()


def test_fuzz_weights_text_garbage(tmp_path_factory, capsys):
    """Not a weights file at all: text lines named ``.pt``."""
    folder = tmp_path_factory.mktemp("wt")
    lines = ["PK\x03\x04 not a zip", "\x80\x02}q\x00.", "state_dict = 1", ""]

    @given(text_lines(lines))
    def inner(text):
        path = write_variant(folder / "text.pt", text)
        check_file("weights/text", lambda: _read_and_load(path), path)
        check_cli("weights/text", ["weights", "show", str(path)], (path.name,), capsys)

    inner()


def test_weights_regressions(tmp_path, weights_samples, capsys):
    """What the fuzzer found, kept as fixed cases: a legacy pickle claiming a 4 GiB string (read
    from a file object, the claim was allocated), cards with fields of the wrong type, keys and
    card text with line breaks, complex or bool tensors."""
    from evsmap.train.init import load_encoder_weights

    legacy = weights_samples["legacy"]
    at = legacy.index(b"X\x10\x00\x00\x00protocol_version")
    huge = legacy[:at + 1] + b"\xf0\xff\xff\xff" + legacy[at + 5:]
    path = write_variant(tmp_path / "huge-string.pt", huge)
    check_file("weights/regressions", lambda: _read_and_load(path), path)
    check_cli("weights/regressions", ["weights", "show", str(path)], (path.name,), capsys)
    for options in ([1, 2], "x", {1: 2}):
        path = tmp_path / "list-options.pt"
        path.write_bytes(_saved({"state_dict": _tiny_state(),
                                 "card": {"model": "tiny", "options": options}}))
        check_file("weights/regressions", lambda p=path: _read_and_load(p), path)
    for card in ({"model": "x", "options": {1: 2, "a": 3}}, {"model": "x", "val_miou": 10**400},
                 {(1, 2): {(3,): 4}, "model": "x"}):  # sorted mixed keys, float(), JSON keys
        path = tmp_path / "odd-card.pt"
        path.write_bytes(_saved({"state_dict": _tiny_state(), "card": card}))
        for argv in (["weights", "show", str(path)], ["weights", "list", str(path), "--json"],
                     ["weights", "show", str(path), "--json"], ["weights", "list", str(path)]):
            check_cli("weights/regressions", argv, (path.name,), capsys)
    for obj in ({"state_dict": {**_tiny_state(), "odd\nkey": torch.zeros(1)}},
                {"state_dict": _tiny_state(), "card": {"model": "x\ny", "options": {"a": "b\nc"}}},
                {"state_dict": {"odd\nkey": torch.zeros(1)}, "card": {"model": "feagnet-s"}}):
        path = tmp_path / "line-breaks.pt"  # keys and card text reach the messages
        path.write_bytes(_saved(obj))
        check_file("weights/regressions", lambda p=path: _read_and_load(p), path)
        check_file("weights/regressions", lambda p=path: load_encoder_weights(_Tiny(), p), path)
        check_cli("weights/regressions", ["weights", "convert", str(path), "--out",
                                          str(tmp_path / "out.pt"), "--force"], (path.name,),
                  capsys)
    for dtype in (torch.complex64, torch.bool):  # cast silently before: now refused
        path = tmp_path / "complex.pt"
        path.write_bytes(_saved({k: v.to(dtype) for k, v in _tiny_state().items()}))
        with pytest.raises(DataFormatError, match="dtype mismatch"):
            _read_and_load(path)
    path = tmp_path / "int-model.pt"
    path.write_bytes(_saved({"state_dict": _tiny_state(), "card": {"model": 3}}))
    check_file("weights/regressions", lambda: _read_and_load(path), path)
    check_cli("weights/regressions", ["weights", "convert", str(path), "--out",
                                      str(tmp_path / "out.pt")], (path.name,), capsys)
