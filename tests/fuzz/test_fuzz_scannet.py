"""Fuzz targets for ScanNet's files (docs/robustness.md): the ``.sens`` stream (its header and its
frames: mutated bytes anywhere, and structured edits of the header's fields and a frame's sizes),
the labelled-mesh PLY and ``scannetv2-labels.combined.tsv``, and ``evsmap info`` on a scene with
a mutated ``.sens``. The scene is the box room of tests/readers/scannet_scene.py; the property
(tests/fuzz/harness.py) is a normal return or one line naming the file."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from evsmap.readers.scannet.labelmap import read_label_table
from evsmap.readers.scannet.mesh import read_label_mesh, voxelise
from evsmap.readers.scannet.reader import ScanNetSequence
from evsmap.readers.scannet.sens import FRAME_HEADER
from tests.fuzz.harness import check_cli, check_file, mutated_bytes, text_lines, write_variant
from tests.readers import scannet_scene as scene

NAME = "scene0000_00"


@pytest.fixture(scope="module")
def scannet_root(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("scannet-fuzz")
    scene.write_scene(root, NAME, frames=3, lost=1)
    return root


def _read_some(path: Path) -> None:
    seq = ScanNetSequence(path=path, labels="mesh")
    for i in range(len(seq)):
        frame = seq.frame(i)
        assert frame.depth.shape == frame.rgb.shape[:2]


def _header_end(data: bytes) -> int:
    (n,) = struct.unpack_from("<Q", data, 4)
    return 4 + 8 + n + 64 * 4 + 4 * 4 + 2 * 4 + 4 + 4 + 8


@st.composite
def sens_edits(draw, data: bytes) -> bytes:
    """A field of the header (version, name length, compressions, sizes, depth shift, frame
    count) or of the first frame (time stamps, sizes) set to an edge value."""
    end = _header_end(data)
    fields = {"version": (0, "<I"), "name_len": (4, "<Q"),
              "color_comp": (end - 8 - 4 - 16 - 8, "<i"),
              "depth_comp": (end - 8 - 4 - 16 - 4, "<i"),
              "color_w": (end - 8 - 4 - 16, "<I"), "depth_h": (end - 8 - 4 - 4, "<I"),
              "shift": (end - 8 - 4, "<f"), "frames": (end - 8, "<Q"),
              "color_bytes": (end + 64 + 16, "<Q"), "depth_bytes": (end + 64 + 24, "<Q")}
    name = draw(st.sampled_from(sorted(fields)))
    offset, fmt = fields[name]
    if fmt == "<f":
        value = draw(st.sampled_from([0.0, -1.0, float("nan"), float("inf"), 1e-30, 1e30]))
    elif fmt == "<i":
        value = draw(st.integers(-2**31, 2**31 - 1))
    elif fmt == "<I":
        value = draw(st.sampled_from([0, 1, 2**15, 2**15 + 1, 2**32 - 1]))
    else:
        value = draw(st.sampled_from([0, 1, 2**20, 2**40, 2**63, 2**64 - 1]))
    out = bytearray(data)
    struct.pack_into(fmt, out, offset, value)
    return bytes(out)


def test_fuzz_sens(scannet_root):
    path = scannet_root / "scans" / NAME / f"{NAME}.sens"
    original = path.read_bytes()
    assert FRAME_HEADER.size == 96

    @given(st.one_of(sens_edits(original), mutated_bytes(original)))
    def run(data: bytes) -> None:
        write_variant(path, data)
        try:
            check_file("scannet/sens", lambda: _read_some(path.parent), path)
        finally:
            path.write_bytes(original)

    run()


def test_fuzz_label_mesh(scannet_root):
    path = scannet_root / "scans" / NAME / f"{NAME}_vh_clean_2.labels.ply"
    original = path.read_bytes()

    def read() -> None:
        mesh = read_label_mesh(path)
        if len(mesh.faces) and np.ptp(mesh.vertices, axis=0).max() < 100:
            voxelise(mesh, 0.05)

    @given(mutated_bytes(original))
    def run(data: bytes) -> None:
        write_variant(path, data)
        try:
            check_file("scannet/label-mesh", read, path)
        finally:
            path.write_bytes(original)

    run()


def test_fuzz_label_table(scannet_root):
    path = scannet_root / "scannetv2-labels.combined.tsv"
    original = path.read_text()

    @given(st.one_of(text_lines(original.splitlines()), mutated_bytes(original.encode())))
    def run(data) -> None:
        write_variant(path, data)
        try:
            check_file("scannet/label-table", lambda: read_label_table(path), path)
        finally:
            path.write_text(original)

    run()


def test_fuzz_scannet_cli(scannet_root, capsys):
    path = scannet_root / "scans" / NAME / f"{NAME}.sens"
    original = path.read_bytes()

    @given(mutated_bytes(original, max_ops=2), st.booleans())
    def run(data: bytes, skip: bool) -> None:
        write_variant(path, data)
        try:
            check_cli("scannet/cli", ["info", str(path.parent)] + (["--skip-bad"] if skip else []),
                      (path.name, NAME), capsys)
        finally:
            path.write_bytes(original)

    run()
