"""Fuzz targets for the recorded-sequence readers (docs/robustness.md): TUM RGB-D lists
(``rgb.txt``, ``depth.txt``, ``groundtruth.txt``, ``labels.txt``, ``intrinsics.txt``), Microsoft
7-Scenes folders (pose files, ``camera-intrinsics.txt``, missing and extra frame files), the
folder ``evsmap synth --out`` writes (and the runner's cached rendering of it) and the command
line (``evsmap info`` / ``evsmap map`` with and without ``--skip-bad``) on mutated folders.

Every target builds a small folder in a temporary directory from the real samples (the samples
themselves are only read), replaces one file per example and opens the folder with the
registered reader, reading a frame or two; the property (tests/fuzz/harness.py) is a normal
return or one line naming the file or the folder.
"""

from __future__ import annotations

import io
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st
from PIL import Image

from evsmap.errors import EvsmapError
from evsmap.readers.detect import open_sequence
from evsmap.readers.sevenscenes import open_sevenscenes
from evsmap.readers.tum import associate, open_tum
from tests.fuzz.harness import check_cli, check_file, mutated_bytes, text_lines, write_variant

TUM_NAME = "rgbd_dataset_freiburg1_xyz"
TUM_FRAMES = 3
SEVEN_FRAMES = 3
LABEL_SAMPLE = "nyuv2_samples/label40/000433.png"


# ----------------------------------------------------------------------------- folders
def _link(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.is_symlink() or dst.exists():
        dst.unlink()
    try:
        os.symlink(src, dst)
    except OSError:  # pragma: no cover - no symlinks (Windows without the privilege)
        shutil.copyfile(src, dst)


def _data_lines(path: Path) -> tuple[list[str], list[str]]:
    lines = path.read_text().splitlines()
    return [x for x in lines if x.startswith("#")], [x for x in lines if not x.startswith("#")]


def build_tum(base: Path, tum_dir: Path, *, labels: bool = False) -> Path:
    """A TUM folder of the first :data:`TUM_FRAMES` depth and RGB images of ``tum_dir`` (its
    images linked), with the ground truth around them; ``labels``: a ``labels.txt`` and label
    images (NYUv2's, 640x480) for each depth image."""
    root = base / TUM_NAME
    root.mkdir(parents=True, exist_ok=True)
    stamps = []
    for name in ("rgb.txt", "depth.txt"):
        head, rows = _data_lines(tum_dir / name)
        rows = rows[:TUM_FRAMES]
        (root / name).write_text("\n".join(head + rows) + "\n")
        for row in rows:
            stamp, rel = row.split()
            _link(tum_dir / rel, root / rel)
            stamps.append(float(stamp))
        if name == "depth.txt" and labels:
            sample = tum_dir.parent / LABEL_SAMPLE
            lab = [f"{r.split()[0]} labels/{r.split()[0]}.png" for r in rows]
            (root / "labels.txt").write_text("# labels\n" + "\n".join(lab) + "\n")
            for r in rows:
                _link(sample, root / "labels" / f"{r.split()[0]}.png")
    head, rows = _data_lines(tum_dir / "groundtruth.txt")
    lo, hi = min(stamps) - 0.05, max(stamps) + 0.05
    rows = [r for r in rows if lo <= float(r.split()[0]) <= hi]
    (root / "groundtruth.txt").write_text("\n".join(head + rows) + "\n")
    return root


def build_sevenscenes(base: Path, seven_dir: Path, frames: int = SEVEN_FRAMES) -> Path:
    """A 7-Scenes sequence folder ``seq-01`` of the sample's first ``frames`` frames (linked)
    and its ``camera-intrinsics.txt`` (copied)."""
    root = base / "seq-01"
    root.mkdir(parents=True, exist_ok=True)
    for n in range(frames):
        for kind in ("color.jpg", "depth.png", "pose.txt"):
            _link(seven_dir / f"frame-{n:06d}.{kind}", root / f"frame-{n:06d}.{kind}")
    shutil.copyfile(seven_dir / "camera-intrinsics.txt", root / "camera-intrinsics.txt")
    return root


def read_some(sequence, count: int = 2) -> None:
    """Read the first ``count`` frames and the last one."""
    n = len(sequence)
    for i in sorted({*range(min(count, n)), n - 1} - {-1}):
        sequence.frame(i)


def text_or_bytes(path: Path) -> st.SearchStrategy[str | bytes]:
    """Line-level edits of the text file ``path`` or byte mutations of it."""
    data = path.read_bytes()
    return st.one_of(text_lines(data.decode().splitlines()), mutated_bytes(data))


class Restore:
    """Put a folder's files back as they were after an example replaced some of them."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.saved: dict[Path, tuple[str, bytes | str]] = {}
        for p in root.rglob("*"):
            if p.is_symlink():
                self.saved[p] = ("link", os.readlink(p))
            elif p.is_file():
                self.saved[p] = ("file", p.read_bytes())

    def __call__(self) -> None:
        for p in sorted(self.root.rglob("*"), key=lambda q: -len(q.parts)):
            if p not in self.saved:
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p)
                else:
                    p.unlink()
        for p, (kind, value) in self.saved.items():
            p.parent.mkdir(parents=True, exist_ok=True)
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            elif p.is_symlink() or p.exists():
                p.unlink()
            if kind == "link":
                os.symlink(value, p)
            else:
                p.write_bytes(value)


# ----------------------------------------------------------------------------- TUM lists
@pytest.fixture(scope="module")
def tum_folder(tmp_path_factory, tum_dir):
    return build_tum(tmp_path_factory.mktemp("tum"), tum_dir)


@pytest.fixture(scope="module")
def tum_labelled(tmp_path_factory, tum_dir):
    return build_tum(tmp_path_factory.mktemp("tumlab"), tum_dir, labels=True)


def _fuzz_tum_list(root: Path, name: str, target: str) -> None:
    path = root / name
    original = path.read_bytes()
    frames = len(open_tum(path=str(root)))
    assert frames >= 2  # the unmutated folder reads
    path.write_bytes(b"\xef\xbb\xbf" + original)  # and so it does saved with a BOM
    try:
        assert len(open_tum(path=str(root))) == frames
    finally:
        path.write_bytes(original)

    @given(text_or_bytes(path))
    def inner(data):
        write_variant(path, data)
        try:
            check_file(target, lambda: read_some(open_tum(path=str(root))), path,
                       names=(root.name,))
        finally:
            path.write_bytes(original)

    inner()


def test_fuzz_tum_rgb_list(tum_folder):
    _fuzz_tum_list(tum_folder, "rgb.txt", "tum/rgb-list")


def test_fuzz_tum_depth_list(tum_folder):
    _fuzz_tum_list(tum_folder, "depth.txt", "tum/depth-list")


def test_fuzz_tum_groundtruth(tum_folder):
    _fuzz_tum_list(tum_folder, "groundtruth.txt", "tum/groundtruth")


def test_fuzz_tum_labels_list(tum_labelled):
    _fuzz_tum_list(tum_labelled, "labels.txt", "tum/labels-list")


_stamp = st.one_of(st.sampled_from([0.0, 0.01, 0.03, 0.0333, 0.05]),
                   st.floats(0.0, 1.3), st.floats(allow_nan=True, allow_infinity=True))


@st.composite
def stamp_lists(draw) -> tuple[list[float], list[float]]:
    """Depth and RGB time stamps (offsets from the first ground-truth sample's): duplicated,
    equal, close, shuffled, non-finite, huge; up to a few hundred of each."""
    n, m = draw(st.integers(0, 300)), draw(st.integers(0, 300))
    base = draw(st.lists(_stamp, min_size=1, max_size=6))
    pick = st.sampled_from(base) | _stamp
    return draw(st.lists(pick, min_size=n, max_size=n)), \
        draw(st.lists(pick, min_size=m, max_size=m))


def test_fuzz_tum_association(tum_folder):
    """Many equal or close stamps (a list written with a frozen clock, concatenated lists) are
    associated one-to-one within the tolerance, in order, without a hang."""
    rgb, depth = tum_folder / "rgb.txt", tum_folder / "depth.txt"
    originals = {p: p.read_bytes() for p in (rgb, depth)}
    images = {p: p.read_text().split()[-1] for p in (rgb, depth)}
    t0 = float((tum_folder / "groundtruth.txt").read_text().splitlines()[3].split()[0])

    def check(t_depth, t_rgb):
        pairs = associate(t_depth, t_rgb, 0.02)
        greedy = associate(t_depth, t_rgb, 0.02, method="greedy")
        for found in (pairs, greedy):  # one-to-one, within the tolerance
            assert len({i for i, _ in found}) == len({j for _, j in found}) == len(found)
            assert all(abs(t_depth[i] - t_rgb[j]) < 0.02 for i, j in found)
        assert len(pairs) >= len(greedy)  # optimal keeps the most pairs
        matched = sorted(pairs, key=lambda p: (t_depth[p[0]], p[0]))
        rgb_order = [t_rgb[j] for _, j in matched]
        assert rgb_order == sorted(rgb_order)  # order-preserving
        open_tum(path=str(tum_folder)).frame(0)

    @given(stamp_lists())
    def inner(stamps):
        for p, offsets in zip((depth, rgb), stamps, strict=True):
            p.write_text("".join(f"{t0 + t!r} {images[p]}\n" for t in offsets))
        t_depth, t_rgb = (np.array([t0 + t for t in offsets]) for offsets in stamps)
        try:
            check_file("tum/association", lambda: check(t_depth, t_rgb), depth,
                       names=(tum_folder.name,))
        finally:
            for p, data in originals.items():
                p.write_bytes(data)

    inner()


_number = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-2**70, 2**70).map(str),
    st.sampled_from(["0", "-1", "1e308", "nan", "inf", "640", "480", "1e-320", "517.3", "x",
                     "1.5", "٣"]))


@st.composite
def intrinsics_texts(draw) -> str:
    """``fx fy cx cy width height`` with any of the six replaced, missing or doubled."""
    fields = ["517.3", "516.5", "318.6", "255.3", "640", "480"]
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, 5))
        fields[i] = draw(_number)
    lines = [" ".join(fields)] * draw(st.sampled_from([1, 1, 1, 0, 2]))
    return "# fx fy cx cy width height\n" + "\n".join(lines) + "\n"


def test_fuzz_tum_intrinsics(tum_folder):
    path = tum_folder / "intrinsics.txt"
    path.write_text("# fx fy cx cy width height\n517.3 516.5 318.6 255.3 640 480\n")
    original = path.read_bytes()
    try:
        @given(st.one_of(intrinsics_texts(), text_or_bytes(path)))
        def inner(data):
            write_variant(path, data)
            try:
                check_file("tum/intrinsics", lambda: read_some(open_tum(path=str(tum_folder))),
                           path, names=(tum_folder.name,))
            finally:
                path.write_bytes(original)

        inner()
    finally:
        path.unlink()


# ----------------------------------------------------------------------------- 7-Scenes
@pytest.fixture(scope="module")
def seven_folder(tmp_path_factory, sevenscenes_dir):
    return build_sevenscenes(tmp_path_factory.mktemp("seven"), sevenscenes_dir)


_entry = st.one_of(st.floats(-2.0, 2.0), st.floats(allow_nan=True, allow_infinity=True),
                   st.sampled_from([0.0, 1.0, -1.0, 1e308, float("nan"), float("inf")]))


@st.composite
def pose_texts(draw, real: np.ndarray) -> str:
    """A 4x4 matrix: the real pose with entries replaced (non-finite, non-rigid, a wrong last
    row), scaled or sheared, or a wrong number of values, printed in a few styles."""
    m = real.copy()
    kind = draw(st.sampled_from(["entries", "scale", "count", "msvc", "random"]))
    if kind == "entries":
        for _ in range(draw(st.integers(1, 4))):
            m[draw(st.integers(0, 3)), draw(st.integers(0, 3))] = draw(_entry)
    elif kind == "scale":
        m[:3, :3] *= draw(st.floats(-3.0, 3.0))
    elif kind == "random":
        m = np.array(draw(st.lists(_entry, min_size=16, max_size=16))).reshape(4, 4)
    values = [repr(float(v)) for v in m.ravel()]
    if kind == "count":
        k = draw(st.integers(0, 20))
        values = (values * 2)[:k]
    if kind == "msvc":
        values[draw(st.integers(0, 15))] = draw(st.sampled_from(
            ["1.#QNAN", "-1.#IND", "1.#INF", "1.#QNAN0", "1.#X", "#"]))
    sep = draw(st.sampled_from([" ", "\t", ",", "  "]))
    rows = [sep.join(values[i:i + 4]) for i in range(0, len(values), 4)]
    return "\n".join(rows) + "\n"


def test_fuzz_sevenscenes_pose(seven_folder, sevenscenes_dir):
    path = seven_folder / "frame-000001.pose.txt"
    real = np.loadtxt(sevenscenes_dir / path.name)
    assert len(open_sevenscenes(path=str(seven_folder))) == SEVEN_FRAMES

    @given(st.one_of(pose_texts(real), text_or_bytes(sevenscenes_dir / path.name)))
    def inner(data):
        path.unlink()
        write_variant(path, data)
        try:
            check_file("sevenscenes/pose",
                       lambda: read_some(open_sevenscenes(path=str(seven_folder)), 2), path)
        finally:
            path.unlink()
            _link(sevenscenes_dir / path.name, path)

    inner()


@st.composite
def k_texts(draw) -> str:
    k = [["585.0", "0.0", "320.0"], ["0.0", "585.0", "240.0"], ["0.0", "0.0", "1.0"]]
    for _ in range(draw(st.integers(1, 3))):
        k[draw(st.integers(0, 2))][draw(st.integers(0, 2))] = draw(_number)
    rows = [" ".join(r) for r in k][:draw(st.integers(0, 3))] if draw(st.booleans()) else \
        [" ".join(r) for r in k]
    return "\n".join(rows) + "\n"


def test_fuzz_sevenscenes_intrinsics(seven_folder):
    path = seven_folder / "camera-intrinsics.txt"
    original = path.read_bytes()

    @given(st.one_of(k_texts(), text_or_bytes(path)))
    def inner(data):
        write_variant(path, data)
        try:
            check_file("sevenscenes/intrinsics",
                       lambda: read_some(open_sevenscenes(path=str(seven_folder)), 1), path,
                       names=(seven_folder.name,))
        finally:
            path.write_bytes(original)

    inner()


_KINDS = ("color.jpg", "color.png", "depth.png", "pose.txt")


@st.composite
def frame_edits(draw) -> list[tuple[str, int, str, str]]:
    """Files removed, added (another frame's file, an empty file, garbage) or renamed to
    another frame number or kind: ``(op, frame number, kind, source)``."""
    number = st.one_of(st.integers(0, SEVEN_FRAMES + 1), st.integers(0, 10**20),
                       st.sampled_from([999999, 10**6, 2**53, 2**63]))
    edits = []
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["remove", "add", "rename", "dir"]))
        edits.append((op, draw(number), draw(st.sampled_from(_KINDS)),
                      draw(st.sampled_from(["copy", "empty", "garbage"]))))
    return edits


def _apply_frame_edits(root: Path, seven_dir: Path, edits) -> None:
    for op, n, kind, source in edits:
        name = f"frame-{n:06d}.{kind}"
        present = sorted(p for p in root.iterdir() if p.name.startswith("frame-"))
        if op == "remove" and present:
            victim = present[n % len(present)]
            victim.rmdir() if victim.is_dir() and not victim.is_symlink() else victim.unlink()
        elif op == "rename" and present:
            src = present[n % len(present)]
            if not (root / name).exists():
                src.rename(root / name)
        elif op == "dir" and not (root / name).exists():
            (root / name).mkdir()
        elif op == "add" and not (root / name).exists():
            if source == "copy":
                ext = "color.jpg" if kind.startswith("color") else kind
                _link(seven_dir / f"frame-000000.{ext}", root / name)
            else:
                (root / name).write_bytes(b"" if source == "empty" else b"\x89PNG\r\n\x1a\n12")


def test_fuzz_sevenscenes_frames(tmp_path_factory, sevenscenes_dir):
    base = tmp_path_factory.mktemp("sevenframes")
    root = build_sevenscenes(base, sevenscenes_dir)
    restore = Restore(root)

    def read_all():
        seq = open_sevenscenes(path=str(root))
        for i in range(len(seq)):
            seq.frame(i)

    @given(frame_edits())
    def inner(edits):
        _apply_frame_edits(root, sevenscenes_dir, edits)
        try:
            check_file("sevenscenes/frames", read_all, root)
        finally:
            restore()

    inner()


def test_fuzz_sevenscenes_depth_header(tmp_path_factory, sevenscenes_dir):
    """The first depth image's header gives the size of ``camera-intrinsics.txt``'s camera:
    a header claiming any size (valid CRC) is read without allocating, and the frame refused."""
    from tests.fuzz.test_fuzz_images import png_with_size

    root = build_sevenscenes(tmp_path_factory.mktemp("sevenhuge"), sevenscenes_dir, 1)
    path = root / "frame-000000.depth.png"
    original = path.resolve().read_bytes()
    path.unlink()
    side = st.one_of(st.integers(0, 2**31 - 1), st.sampled_from([0, 1, 640, 480, 100000]))

    @given(side, side)
    def inner(width, height):
        write_variant(path, png_with_size(original, width, height))
        check_file("sevenscenes/depth-header",
                   lambda: read_some(open_sevenscenes(path=str(root)), 1), path)

    inner()


_SEQ_KINDS = ("frames", "frames", "empty", "file", "loop", "dangling", "zip", "absent")


def test_fuzz_sevenscenes_scene_folder(tmp_path_factory, sevenscenes_dir):
    """A scene folder of ``seq-NN`` entries that are sequences, empty folders, files, links
    that loop or dangle, or zips, read with any ``sequence=``."""
    base = tmp_path_factory.mktemp("scene")
    counter = iter(range(10**9))

    @given(st.lists(st.sampled_from(_SEQ_KINDS), min_size=1, max_size=3),
           st.one_of(st.none(), st.integers(-1, 4), st.sampled_from(
               ["seq-01", "seq-1", "02", "seq-03", "x", "", " 1 ", "9" * 30, "seq-"])))
    @example(kinds=["frames", "loop"], sequence=None)  # a looping link once hid every sequence
    def inner(kinds, sequence):
        scene = base / f"scene{next(counter)}"
        scene.mkdir()
        for n, kind in enumerate(kinds, 1):
            entry = scene / f"seq-{n:02d}"
            if kind == "frames":
                built = build_sevenscenes(base / f"build{next(counter)}", sevenscenes_dir, 1)
                built.rename(entry)
            elif kind == "empty":
                entry.mkdir()
            elif kind == "file":
                entry.write_text("x")
            elif kind == "loop":
                os.symlink(entry.name, entry)
            elif kind == "dangling":
                os.symlink(scene / "nowhere", entry)
            elif kind == "zip":
                (scene / f"seq-{n:02d}.zip").write_bytes(b"PK\x05\x06" + b"\0" * 18)
        check_file("sevenscenes/scene-folder",
                   lambda: read_some(open_sevenscenes(path=str(scene), sequence=sequence), 1),
                   scene)
        if kinds[0] == "frames" and sequence in (None, 1, "seq-01", "seq-1", " 1 "):
            # the other entries, however broken, do not hide the first sequence
            assert len(open_sevenscenes(path=str(scene), sequence=sequence)) == 1

    inner()


# ----------------------------------------------------------------------------- evsmap synth
SYNTH_FILES = ("rgb.txt", "depth.txt", "groundtruth.txt", "labels.txt", "intrinsics.txt",
               "evsmap.json")


@pytest.fixture(scope="module")
def synth_folder(tmp_path_factory):
    from evsmap.cli.main import main

    out = tmp_path_factory.mktemp("synth") / "synth"
    assert main(["synth", "--out", str(out), "--frames", "3", "--width", "40",
                 "--height", "30"]) == 0
    return out


@st.composite
def json_variants(draw, original: dict) -> str:
    """``evsmap.json`` with a key dropped or its value replaced by another JSON value, or a
    non-object document."""
    values = st.recursive(
        st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=6),
        lambda kids: st.lists(kids, max_size=3) | st.dictionaries(st.text(max_size=4), kids,
                                                                   max_size=3),
        max_leaves=6)
    info = dict(original)
    kind = draw(st.sampled_from(["replace", "drop", "document"]))
    if kind == "document":
        return json.dumps(draw(values))
    key = draw(st.sampled_from(sorted(info)))
    if kind == "drop":
        del info[key]
    else:
        info[key] = draw(values)
    return json.dumps(info)


def _synth_file_strategy(root: Path) -> st.SearchStrategy[tuple[str, str | bytes]]:
    meta = json.loads((root / "evsmap.json").read_text())
    options = [st.tuples(st.just(name), text_or_bytes(root / name)) for name in SYNTH_FILES]
    options.append(st.tuples(st.just("evsmap.json"), json_variants(meta)))
    return st.one_of(*options)


def test_fuzz_synth_lists(synth_folder):
    restore = Restore(synth_folder)
    assert len(open_sequence(str(synth_folder))) == 3

    @given(_synth_file_strategy(synth_folder))
    def inner(choice):
        name, data = choice
        path = write_variant(synth_folder / name, data)
        try:
            check_file("synth/lists", lambda: read_some(open_sequence(str(synth_folder)), 3),
                       path, names=(synth_folder.name,))
        finally:
            restore()

    inner()


def test_fuzz_synth_images(synth_folder):
    restore = Restore(synth_folder)
    images = sorted(p.relative_to(synth_folder) for p in synth_folder.rglob("*.png"))
    samples = {str(p): (synth_folder / p).read_bytes() for p in images}

    @given(st.sampled_from(sorted(samples)).flatmap(
        lambda rel: st.tuples(st.just(rel), mutated_bytes(samples[rel]))))
    def inner(choice):
        rel, data = choice
        path = write_variant(synth_folder / rel, data)
        try:
            check_file("synth/images", lambda: read_some(open_sequence(str(synth_folder)), 3),
                       path, names=(synth_folder.name,))
        finally:
            restore()

    inner()


def test_fuzz_cached_synthetic():
    """The runner's cached rendering read back (evsmap.synth.cached): a corrupted cache folder
    is a one-line error naming it, never a traceback."""
    from evsmap.synth.cached import CachedSynthetic, rendered_folder

    options = {"frames": 2, "width": 32, "height": 24}
    folder = rendered_folder(options)
    restore = Restore(folder)
    strategy = st.one_of(
        _synth_file_strategy(folder),
        st.sampled_from(sorted(str(p.relative_to(folder)) for p in folder.rglob("*.png")))
        .flatmap(lambda rel: st.tuples(st.just(rel), mutated_bytes((folder / rel).read_bytes()))))

    @given(strategy)
    def inner(choice):
        name, data = choice
        path = write_variant(folder / name, data)
        try:
            check_file("synth/cached", lambda: read_some(CachedSynthetic(**options), 2), path,
                       names=(folder.name,))
        finally:
            restore()

    inner()
    # the message says what to do about a damaged cache
    (folder / "depth.txt").write_text("not a list\n")
    try:
        with pytest.raises(EvsmapError, match="delete .* to render it again"):
            CachedSynthetic(**options)
    finally:
        restore()
    assert len(CachedSynthetic(**options)) == 2


# ----------------------------------------------------------------------------- command line
def _cli_strategy(root: Path, lists: tuple[str, ...]) -> st.SearchStrategy:
    """A list file's edit, or an image of the folder mutated."""
    images = sorted(str(p.relative_to(root)) for p in root.rglob("*")
                    if p.suffix in (".png", ".jpg"))
    return st.one_of(
        *[st.tuples(st.just(name), text_or_bytes(root / name)) for name in lists],
        st.sampled_from(images).flatmap(lambda rel: st.tuples(
            st.just(rel), mutated_bytes((root / rel).resolve().read_bytes(), max_ops=2))))


def _fuzz_cli(root: Path, lists: tuple[str, ...], target: str, capsys, tmp: Path) -> None:
    restore = Restore(root)
    commands = [["info", str(root)], ["info", str(root), "--skip-bad"],
                ["map", str(root), "--updater", "orgb", "--frames", "2",
                 "--out", str(tmp / "map.ot"), "--overwrite"],
                ["map", str(root), "--updater", "orgb", "--frames", "2", "--skip-bad"]]

    @given(_cli_strategy(root, lists), st.sampled_from(commands))
    def inner(choice, argv):
        name, data = choice
        path = root / name
        if path.is_symlink():
            path.unlink()
        write_variant(path, data)
        try:
            check_cli(target, argv, (root.name, Path(name).name), capsys)
        finally:
            restore()

    inner()


def test_fuzz_cli_tum(tmp_path_factory, tum_dir, capsys):
    root = build_tum(tmp_path_factory.mktemp("clitum"), tum_dir)
    _fuzz_cli(root, ("rgb.txt", "depth.txt", "groundtruth.txt"), "cli/tum", capsys,
              tmp_path_factory.mktemp("clitum-out"))


def test_fuzz_cli_sevenscenes(tmp_path_factory, sevenscenes_dir, capsys):
    root = build_sevenscenes(tmp_path_factory.mktemp("cliseven"), sevenscenes_dir)
    _fuzz_cli(root, ("camera-intrinsics.txt", "frame-000001.pose.txt"), "cli/sevenscenes",
              capsys, tmp_path_factory.mktemp("cliseven-out"))


@st.composite
def label_images(draw, root: Path) -> tuple[str, bytes]:
    """One of the folder's label images replaced by a valid PNG of the right or a wrong size
    holding any class id (beyond the 40 classes, void)."""
    rel = draw(st.sampled_from(sorted(str(p.relative_to(root)) for p in
                                      (root / "labels").iterdir())))
    w, h = draw(st.sampled_from([(40, 30), (40, 30), (30, 40), (1, 1)]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    high = draw(st.sampled_from([40, 41, 256]))
    buf = io.BytesIO()
    Image.fromarray(rng.integers(0, high, (h, w)).astype(np.uint8)).save(buf, format="PNG")
    return rel, buf.getvalue()


def test_fuzz_cli_synth(tmp_path_factory, capsys):
    from evsmap.cli.main import main

    root = tmp_path_factory.mktemp("clisynth") / "synth"
    assert main(["synth", "--out", str(root), "--frames", "3", "--width", "40",
                 "--height", "30"]) == 0
    restore = Restore(root)
    commands = [["info", str(root)],
                ["map", str(root), "--updater", "orgb", "--frames", "2"],
                ["map", str(root), "--updater", "multiclass-bayes", "--frames", "2"],
                ["map", str(root), "--updater", "classic-semantic", "--frames", "2",
                 "--skip-bad"]]
    meta = json.loads((root / "evsmap.json").read_text())

    @given(st.one_of(_cli_strategy(root, SYNTH_FILES), label_images(root),
                     st.tuples(st.just("evsmap.json"), json_variants(meta))),
           st.sampled_from(commands))
    def inner(choice, argv):
        name, data = choice
        write_variant(root / name, data)
        try:
            check_cli("cli/synth", argv, (root.name, Path(name).name), capsys)
        finally:
            restore()

    inner()


def test_skip_bad_reports_a_corrupt_frame(tmp_path_factory, tum_dir, sevenscenes_dir, capsys):
    """The documented skip: ``--skip-bad`` exits 0 and reports the frame it left out."""
    from evsmap.cli.main import main

    tum = build_tum(tmp_path_factory.mktemp("skiptum"), tum_dir)
    seven = build_sevenscenes(tmp_path_factory.mktemp("skipseven"), sevenscenes_dir)
    for root, bad in ((tum, sorted((tum / "depth").iterdir())[1]),
                      (seven, seven / "frame-000001.depth.png")):
        data = bad.resolve().read_bytes()
        bad.unlink()
        bad.write_bytes(data[:100])
        for command in (["info", str(root), "--skip-bad", "--json"],
                        ["map", str(root), "--updater", "orgb", "--frames", "2", "--skip-bad",
                         "--json"]):
            capsys.readouterr()
            assert main(command) == 0
            text = capsys.readouterr().out
            skipped = json.loads(text)["extra"]["skipped"] if command[0] == "map" else \
                json.loads(text)["skipped"]
            assert skipped["count"] == 1 and bad.name in skipped["frames"][0]["reason"], text
        assert check_cli("cli/skip-bad", ["info", str(root)], (bad.name,), capsys) == 2
