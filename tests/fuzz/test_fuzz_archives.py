"""Fuzz targets: the official archives ``evsmap datasets fetch`` unpacks (TUM's ``.tgz``,
7-Scenes' zip holding a zip) and the checks of what comes out of them.

A damaged archive (truncated gzip, bad zip directory, flipped bytes), a member that is a link
or a device, a member or header claiming a huge size: one line naming the archive. A member name
that is absolute or holds ``..``: refused, one line naming the archive and the member, and
nothing is written outside the extraction folder. Unit tests of those refusals close the file,
and a check that no code path unpacks a user's archive with ``extractall``."""

from __future__ import annotations

import dataclasses
import io
import json
import re
import shutil
import stat
import tarfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from PIL import Image

from evsmap import samples
from evsmap.download import CorruptArchiveError, FetchError
from evsmap.sample_archives import extract_sample
from evsmap.samples import SAMPLES, verify_sample
from tests.fuzz.harness import check_cli, check_file, mutated_bytes, write_variant

TOP = "rgbd_dataset_freiburg1_xyz"
TUM = dataclasses.replace(SAMPLES["tum-fr1-xyz"], options={"sequence": TOP, "frames": 2},
                          expected=None)
SEVEN = dataclasses.replace(SAMPLES["sevenscenes-100"],
                            options={**SAMPLES["sevenscenes-100"].options, "frames": 2},
                            expected=None)


def _png(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format="PNG")
    return buf.getvalue()


# -- TUM: a tiny .tgz in the official layout ---------------------------------------------------
def tum_members() -> dict[str, bytes]:
    rng = np.random.default_rng(3)
    members: dict[str, bytes] = {}
    lists = {"rgb": "# color images\n", "depth": "# depth maps\n"}
    for i in range(3):
        t = f"{1305031102.175304 + 0.033 * i:.6f}"
        members[f"rgb/{t}.png"] = _png(rng.integers(0, 256, (4, 6, 3), dtype=np.uint8))
        members[f"depth/{t}.png"] = _png(rng.integers(0, 60000, (4, 6), dtype=np.uint16))
        for kind in lists:
            lists[kind] += f"{t} {kind}/{t}.png\n"
    members["rgb.txt"] = lists["rgb"].encode()
    members["depth.txt"] = lists["depth"].encode()
    members["groundtruth.txt"] = b"# ground truth\n1305031102.1 1 2 3 0 0 0 1\n"
    return members


def tar_bytes(members: dict[str, bytes], extra: list[tarfile.TarInfo] = (),
              compress: bool = True) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz" if compress else "w") as tf:
        for name, data in members.items():
            info = tarfile.TarInfo(f"{TOP}/{name}")
            info.size = len(data)
            tf.addfile(info, io.BytesIO(data))
        for info in extra:
            tf.addfile(info, io.BytesIO(b"\0" * info.size) if info.isfile() else None)
    return buf.getvalue()


def _gzip(data: bytes) -> bytes:
    import gzip

    return gzip.compress(data, mtime=0)


class Extraction:
    """An archive file, a work folder and a fresh output folder per example, inside ``base``;
    :meth:`outside` lists anything that appeared in ``base`` besides them."""

    def __init__(self, base: Path, archive_name: str) -> None:
        self.base = base
        self.archive = base / "cache" / archive_name
        self.archive.parent.mkdir(parents=True, exist_ok=True)
        self.n = 0

    def run(self, sample: samples.Sample) -> None:
        self.n += 1
        out = self.base / "x" / "out"
        work = self.base / "x" / "work"
        shutil.rmtree(self.base / "x", ignore_errors=True)
        out.mkdir(parents=True)
        work.mkdir()
        extract_sample(sample, {self.archive.name: self.archive}, out, work)

    def outside(self) -> list[str]:
        return sorted(p.name for p in self.base.iterdir() if p.name not in ("cache", "x"))


def test_fuzz_tgz_bytes(tmp_path):
    """Bytes of the compressed archive and of the tar inside it mutated."""
    ex = Extraction(tmp_path, "rgbd_dataset_freiburg1_xyz.tgz")
    raw = tar_bytes(tum_members(), compress=False)
    packed = _gzip(raw)

    @given(st.one_of(mutated_bytes(packed), mutated_bytes(raw).map(_gzip)))
    def inner(data):
        write_variant(ex.archive, data)
        check_file("archives/tgz-bytes", lambda: ex.run(TUM), ex.archive)

    inner()
    assert ex.outside() == []


def _tar_info(name: str, kind: str, size: int = 0, link: str = "") -> tarfile.TarInfo:
    info = tarfile.TarInfo(name)
    info.type = {"file": tarfile.REGTYPE, "symlink": tarfile.SYMTYPE, "hardlink": tarfile.LNKTYPE,
                 "chr": tarfile.CHRTYPE, "blk": tarfile.BLKTYPE, "fifo": tarfile.FIFOTYPE,
                 "dir": tarfile.DIRTYPE}[kind]
    info.size = size if kind == "file" else 0
    info.linkname = link
    return info


TUM_NAMES = ["rgb.txt", "groundtruth.txt", "rgb/{t}.png", "depth/{t}.png"]
BAD_NAMES = ["/etc/evil.png", "../evil.png", f"{TOP}/rgb/../../evil.png",
             f"{TOP}/../evil.png", "C:/evil.png", "\\evil.png", f"{TOP}/rgb/..\\..\\evil.png"]


def _first_stamp() -> str:
    return f"{1305031102.175304:.6f}"


@st.composite
def tum_variants(draw: st.DrawFn) -> bytes:
    """The archive with one member of the wrong kind, an unsafe name, or a huge claimed size."""
    members = tum_members()
    target = draw(st.sampled_from(TUM_NAMES)).format(t=_first_stamp())
    op = draw(st.sampled_from(["kind", "name", "size", "longname", "listed"]))
    extra: list[tarfile.TarInfo] = []
    if op == "kind":
        data = members.pop(target)
        kind = draw(st.sampled_from(["symlink", "hardlink", "chr", "blk", "fifo", "dir"]))
        extra.append(_tar_info(f"{TOP}/{target}", kind, len(data), link="/etc/passwd"))
    elif op == "name":
        extra.append(_tar_info(draw(st.sampled_from(BAD_NAMES)), "file", 4))
    elif op == "listed":
        # a list naming a file through '..', with the member the name points at
        bad = draw(st.sampled_from(["rgb/../../evil.png", "rgb/sub/x.png", "rgb/", "evil.png"]))
        members["rgb.txt"] = members["rgb.txt"].replace(
            f"rgb/{_first_stamp()}.png".encode(), bad.encode())
        members[bad] = b"x"
    if op in ("size", "longname"):
        raw = bytearray(tar_bytes(members, extra, compress=False))
        if op == "size":
            # the first member's header claims a huge size (its checksum kept right)
            claim = draw(st.sampled_from([2**33 - 1, 3 * 2**30, 2**40]))
            info = tarfile.TarInfo(f"{TOP}/{next(iter(members))}")
            info.size = claim
            header = info.tobuf(format=tarfile.GNU_FORMAT)
        else:
            info = tarfile.TarInfo("././@LongLink")
            info.type = tarfile.GNUTYPE_LONGNAME
            info.size = draw(st.sampled_from([3 * 2**30, 2**33 - 1]))
            header = info.tobuf(format=tarfile.GNU_FORMAT)
        return _gzip(bytes(header[:512]) + bytes(raw[512:] if op == "size" else raw))
    return tar_bytes(members, extra)


def test_fuzz_tgz_members(tmp_path):
    ex = Extraction(tmp_path, "rgbd_dataset_freiburg1_xyz.tgz")

    @given(tum_variants())
    def inner(data):
        write_variant(ex.archive, data)
        check_file("archives/tgz-members", lambda: ex.run(TUM), ex.archive)
        assert not list(tmp_path.rglob("evil*")), "written outside the extraction folder"

    inner()
    assert ex.outside() == []


# -- 7-Scenes: a zip holding seq-01.zip ---------------------------------------------------------
def seven_inner(frames: int = 2) -> dict[str, bytes]:
    rng = np.random.default_rng(4)
    members = {}
    for i in range(frames):
        stem = f"seq-01/frame-{i:06d}"
        members[f"{stem}.color.png"] = _png(rng.integers(0, 256, (4, 6, 3), dtype=np.uint8))
        members[f"{stem}.depth.png"] = _png(rng.integers(0, 6000, (4, 6), dtype=np.uint16))
        members[f"{stem}.pose.txt"] = b"1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n"
    return members


def zip_bytes(members: dict[str, bytes], *, infos: dict[str, zipfile.ZipInfo] | None = None,
              method: int = zipfile.ZIP_DEFLATED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=method) as zf:
        for name, data in members.items():
            info = (infos or {}).get(name)
            if info is None:
                zf.writestr(name, data)
            else:
                zf.writestr(info, data)
    return buf.getvalue()


def seven_archive(inner: bytes) -> bytes:
    return zip_bytes({"redkitchen/TrainSplit.txt": b"sequence1\n", "redkitchen/seq-01.zip": inner},
                     method=zipfile.ZIP_STORED)


def test_fuzz_zip_bytes(tmp_path):
    """Bytes of the outer zip (which stores the inner one as is) and of the inner zip mutated."""
    ex = Extraction(tmp_path, "redkitchen.zip")
    inner_zip = zip_bytes(seven_inner())
    outer = seven_archive(inner_zip)

    @given(st.one_of(mutated_bytes(outer), mutated_bytes(inner_zip).map(seven_archive)))
    def inner(data):
        write_variant(ex.archive, data)
        check_file("archives/zip-bytes", lambda: ex.run(SEVEN), ex.archive)

    inner()
    assert ex.outside() == []


def _zip_info(name: str, mode: int) -> zipfile.ZipInfo:
    info = zipfile.ZipInfo(name)
    info.create_system = 3
    info.external_attr = mode << 16
    return info


def _patch_sizes(data: bytes, name: str, compress_size: int | None, file_size: int | None
                 ) -> bytes:
    """The zip with the central directory's sizes of ``name`` replaced."""
    import struct

    out = bytearray(data)
    start = 0
    while (i := out.find(b"PK\x01\x02", start)) >= 0:
        n = struct.unpack_from("<H", out, i + 28)[0]
        if out[i + 46:i + 46 + n].decode() == name:
            if compress_size is not None:
                struct.pack_into("<I", out, i + 20, compress_size)
            if file_size is not None:
                struct.pack_into("<I", out, i + 24, file_size)
        start = i + 4
    return bytes(out)


@st.composite
def seven_variants(draw: st.DrawFn) -> bytes:
    members = seven_inner()
    target = draw(st.sampled_from(sorted(members)))
    op = draw(st.sampled_from(["symlink", "device", "name", "size", "method", "encrypted",
                               "outer-name", "outer-size"]))
    if op in ("symlink", "device"):
        mode = (stat.S_IFLNK | 0o777) if op == "symlink" else (stat.S_IFCHR | 0o600)
        return seven_archive(zip_bytes(members, infos={target: _zip_info(target, mode)}))
    if op == "name":
        members[draw(st.sampled_from(BAD_NAMES))] = b"x"
        return seven_archive(zip_bytes(members))
    if op == "size":
        claim = draw(st.sampled_from([2**32 - 1, 3 * 2**30, 2**31]))
        which = draw(st.sampled_from(["compress", "file", "both"]))
        inner = _patch_sizes(zip_bytes(members), target,
                             claim if which != "file" else None,
                             claim if which != "compress" else None)
        return seven_archive(inner)
    if op in ("method", "encrypted"):
        inner = bytearray(zip_bytes(members))
        import struct

        i = inner.find(b"PK\x01\x02")
        if op == "method":
            struct.pack_into("<H", inner, i + 10, draw(st.sampled_from([1, 6, 12, 14, 99])))
        else:
            flags = struct.unpack_from("<H", inner, i + 8)[0]
            struct.pack_into("<H", inner, i + 8, flags | 1)
        return seven_archive(bytes(inner))
    if op == "outer-name":
        return zip_bytes({draw(st.sampled_from(BAD_NAMES)): b"x",
                          "redkitchen/seq-01.zip": zip_bytes(members)})
    return _patch_sizes(seven_archive(zip_bytes(members)), "redkitchen/seq-01.zip",
                        2**32 - 1, 2**32 - 1)


def test_fuzz_zip_members(tmp_path):
    ex = Extraction(tmp_path, "redkitchen.zip")

    @given(seven_variants())
    def inner(data):
        write_variant(ex.archive, data)
        check_file("archives/zip-members", lambda: ex.run(SEVEN), ex.archive)
        assert not list(tmp_path.rglob("evil*")), "written outside the extraction folder"

    inner()
    assert ex.outside() == []


# -- the checks of the extracted files ----------------------------------------------------------
def test_fuzz_verify_images(tmp_path):
    """``pixels`` / ``mean-rgb-2x2`` / ``depth-stats`` checks of a damaged extracted image: one
    line naming the file (where the sample would go)."""
    folder = tmp_path / "stage"
    folder.mkdir()
    depth = _png(np.arange(24, dtype=np.uint16).reshape(4, 6) * 100)
    rules = (samples.Rule("*.png", "pixels"), samples.Rule("*.jpg", "mean-rgb-2x2"),
             samples.Rule("*.dpt", "depth-stats", (0.1, 1.0, 1.0, 1.0)))
    sample = dataclasses.replace(SAMPLES["sevenscenes-100"], rules=rules)
    display = tmp_path / "root" / "sevenscenes_100"

    i = depth.find(b"IDAT")
    claims = st.sampled_from([depth[:i - 4] + b"\xff\xff\xff\x00" + depth[i:]])

    @given(st.one_of(mutated_bytes(depth), claims), st.sampled_from(["a.png", "a.jpg", "a.dpt"]))
    def inner(data, name):
        for old in folder.iterdir():
            old.unlink()
        write_variant(folder / name, data)
        variant = dataclasses.replace(sample, expected={name: "0" * 64 if name == "a.png"
                                                        else (0.0,) * 12})
        check_file("archives/verify", lambda: verify_sample(variant, folder, display=display),
                   folder / name)

    inner()


# -- the command line ---------------------------------------------------------------------------
def test_fuzz_fetch_cli(tmp_path, capsys, monkeypatch):
    """``evsmap datasets fetch tum-fr1-xyz`` with a damaged archive already in the download
    folder (no network: the catalogue entry has no size or checksum to fetch anew for)."""
    monkeypatch.setitem(SAMPLES, "tum-fr1-xyz", TUM)
    cache = tmp_path / "cache"
    cache.mkdir()
    archive = cache / "rgbd_dataset_freiburg1_xyz.tgz"
    raw = tar_bytes(tum_members(), compress=False)

    @given(st.one_of(mutated_bytes(raw).map(_gzip), tum_variants()))
    def inner(data):
        write_variant(archive, data)
        check_cli("archives/fetch-cli",
                  ["datasets", "fetch", "tum-fr1-xyz", "--out", str(tmp_path / "root"),
                   "--cache-dir", str(cache), "--keep-archive", "--overwrite"],
                  (archive.name,), capsys)

    inner()
    assert not list(tmp_path.rglob("evil*"))


# -- unit tests of the refusals -----------------------------------------------------------------
@pytest.mark.parametrize("name", BAD_NAMES)
def test_tgz_member_outside_is_refused(tmp_path, name):
    ex = Extraction(tmp_path, "rgbd_dataset_freiburg1_xyz.tgz")
    ex.archive.write_bytes(tar_bytes(tum_members(), [_tar_info(name, "file", 4)]))
    with pytest.raises(CorruptArchiveError) as err:
        ex.run(TUM)
    assert str(err.value) == (f"{ex.archive}: member {name!r} has an absolute path or a '..' "
                              "component (refused: it would reach outside the extraction "
                              "folder)")
    assert not list(tmp_path.rglob("evil*")) and ex.outside() == []


def test_tgz_list_naming_a_file_outside_is_refused(tmp_path):
    """rgb.txt naming ``rgb/../../evil.png`` with such a member: the member is refused."""
    ex = Extraction(tmp_path, "rgbd_dataset_freiburg1_xyz.tgz")
    members = tum_members()
    members["rgb.txt"] = members["rgb.txt"].replace(f"rgb/{_first_stamp()}.png".encode(),
                                                    b"rgb/../../evil.png")
    members["rgb/../../evil.png"] = b"x"
    ex.archive.write_bytes(tar_bytes(members))
    with pytest.raises(CorruptArchiveError, match=re.escape(
            f"{ex.archive}: member '{TOP}/rgb/../../evil.png' has an absolute path or a '..'")):
        ex.run(TUM)
    # a nested file that does not climb out: refused by the list's layout
    members = tum_members()
    members["rgb.txt"] = members["rgb.txt"].replace(f"rgb/{_first_stamp()}.png".encode(),
                                                    b"rgb/sub/x.png")
    members["rgb/sub/x.png"] = b"x"
    ex.archive.write_bytes(tar_bytes(members))
    with pytest.raises(FetchError, match=re.escape(
            f"{ex.archive}:{TOP}/rgb.txt: lists 'rgb/sub/x.png', expected rgb/<file>")):
        ex.run(TUM)
    assert not list(tmp_path.rglob("evil*"))


@pytest.mark.parametrize("kind", ["symlink", "hardlink", "chr", "fifo", "dir"])
def test_tgz_member_of_the_wrong_kind(tmp_path, kind):
    ex = Extraction(tmp_path, "rgbd_dataset_freiburg1_xyz.tgz")
    members = tum_members()
    del members["groundtruth.txt"]
    ex.archive.write_bytes(tar_bytes(members, [
        _tar_info(f"{TOP}/groundtruth.txt", kind, link="/etc/passwd")]))
    with pytest.raises(CorruptArchiveError) as err:
        ex.run(TUM)
    what = {"symlink": "a symbolic link", "hardlink": "a hard link", "chr": "a device",
            "fifo": "a FIFO", "dir": "a folder"}[kind]
    assert str(err.value) == (f"{ex.archive}: member {TOP}/groundtruth.txt is {what}, not a "
                              "regular file")


def test_tgz_huge_claims(tmp_path):
    ex = Extraction(tmp_path, "rgbd_dataset_freiburg1_xyz.tgz")
    info = tarfile.TarInfo("././@LongLink")
    info.type = tarfile.GNUTYPE_LONGNAME
    info.size = 3 * 2**30
    ex.archive.write_bytes(_gzip(info.tobuf(format=tarfile.GNU_FORMAT) + b"\0" * 2048))
    with pytest.raises(CorruptArchiveError, match=re.escape(
            f"{ex.archive}: not a readable .tgz archive (a header or member claims")):
        ex.run(TUM)
    members = tum_members()
    big = tarfile.TarInfo(f"{TOP}/groundtruth.txt")
    big.size = 2**33 - 1
    raw = tar_bytes({k: v for k, v in members.items() if k != "groundtruth.txt"}, [],
                    compress=False)
    ex.archive.write_bytes(_gzip(big.tobuf(format=tarfile.GNU_FORMAT) + raw))
    with pytest.raises(CorruptArchiveError, match=re.escape(
            f"{ex.archive}: member {TOP}/groundtruth.txt claims 8589934591 bytes (more than")):
        ex.run(TUM)


@pytest.mark.parametrize("name", BAD_NAMES)
def test_zip_member_outside_is_refused(tmp_path, name):
    ex = Extraction(tmp_path, "redkitchen.zip")
    members = seven_inner()
    members[name] = b"x"
    ex.archive.write_bytes(seven_archive(zip_bytes(members)))
    with pytest.raises(CorruptArchiveError) as err:
        ex.run(SEVEN)
    assert str(err.value) == (f"{ex.archive}: member {name!r} has an absolute path or a '..' "
                              "component (refused: it would reach outside the extraction "
                              "folder)")
    ex.archive.write_bytes(zip_bytes({name: b"x", "redkitchen/seq-01.zip": b""}))
    with pytest.raises(CorruptArchiveError, match=re.escape(f"{ex.archive}: member {name!r}")):
        ex.run(SEVEN)


def test_zip_symlink_and_huge_claims(tmp_path):
    ex = Extraction(tmp_path, "redkitchen.zip")
    members = seven_inner()
    name = "seq-01/frame-000000.pose.txt"
    ex.archive.write_bytes(seven_archive(zip_bytes(members, infos={
        name: _zip_info(name, stat.S_IFLNK | 0o777)})))
    with pytest.raises(CorruptArchiveError, match=re.escape(
            f"{ex.archive}: member seq-01.zip:{name} is a symbolic link, not a regular file")):
        ex.run(SEVEN)
    ex.archive.write_bytes(seven_archive(_patch_sizes(zip_bytes(members), name, None,
                                                      2**32 - 1)))
    with pytest.raises(CorruptArchiveError, match=re.escape(
            f"{ex.archive}: member seq-01.zip:{name} claims 4294967295 bytes")):
        ex.run(SEVEN)


def test_no_extractall_on_user_archives():
    """Nothing in evsmap unpacks an archive wholesale, except tarfile's with filter="data"."""
    root = Path(samples.__file__).resolve().parent
    for path in sorted(root.rglob("*.py")):
        text = path.read_text()
        for match in re.finditer(r"\.extractall\(([^)]*)\)", text):
            assert "filter=\"data\"" in match.group(1) or "filter='data'" in match.group(1), \
                f"{path}: extractall without filter='data'"
            assert "zipfile" not in text or "ZipFile" not in text[max(0, match.start() - 400):
                                                                 match.start()], path


def test_fuzz_fetch_list_cli(tmp_path, capsys):
    """``evsmap datasets fetch --list`` over a data root whose sample manifest
    (``evsmap-sample.json``) is damaged."""
    from evsmap.fetch import manifest_path

    sample = SAMPLES["nyuv2-samples"]
    target = manifest_path(sample, tmp_path)
    target.parent.mkdir(parents=True)
    record = {"format": "evsmap-sample", "sample": sample.name, "date": "2026-01-01T00:00:00",
              "files": [{"path": "rgb/000433.png", "size": 10, "sha256": "0" * 64,
                         "check": "pixels"}], "archives": [], "options": {}}
    original = json.dumps(record, indent=2).encode()
    odd = st.one_of(st.none(), st.integers(), st.floats(allow_nan=True), st.text(max_size=5),
                    st.builds(list), st.builds(dict))

    @st.composite
    def edited(draw: st.DrawFn) -> bytes:
        out = json.loads(original)
        keys = st.sampled_from(sorted(out))
        out[draw(st.one_of(keys, st.sampled_from(["date", "files", "format"])))] = draw(odd)
        return json.dumps(out).encode()

    deep = st.sampled_from([b"[" * 100_000, b'{"format": "evsmap-sample", "date": ' + b"9" * 5000
                            + b"}"])

    @given(st.one_of(mutated_bytes(original), edited(), deep), st.booleans())
    def inner(data, as_json):
        write_variant(target, data)
        check_cli("archives/fetch-list-cli", ["datasets", "fetch", "--list", "--out",
                                              str(tmp_path)] + (["--json"] if as_json else []),
                  (target.name,), capsys)

    inner()


@pytest.mark.parametrize("date", [5, 1.5, ["2026"], True])
def test_fetch_list_with_a_date_that_is_not_text(tmp_path, capsys, date):
    from evsmap.cli.main import main
    from evsmap.fetch import manifest_path

    target = manifest_path(SAMPLES["nyuv2-samples"], tmp_path)
    target.parent.mkdir(parents=True)
    target.write_text(json.dumps({"format": "evsmap-sample", "date": date}))
    assert main(["datasets", "fetch", "--list", "--out", str(tmp_path)]) == 0
    row = [line for line in capsys.readouterr().out.splitlines() if "nyuv2-samples" in line][0]
    assert row.split()[1] == "yes"


# -- NYUv2: the labelled .mat and the class mapping, through the sample's extractor ------------
@pytest.fixture(scope="module")
def nyu_downloads(tmp_path_factory) -> dict[str, bytes]:
    """The two downloads of the NYUv2 sample, tiny: a two-frame labelled file with rawDepths
    and the class mapping."""
    import h5py

    from evsmap.datasets import nyuv2
    from tests.datasets.datasets_fixtures import nyu_arrays, write_nyu_source

    root = tmp_path_factory.mktemp("nyu_downloads")
    arrays = {k: v[:2] for k, v in nyu_arrays(2).items()}
    write_nyu_source(root, arrays)
    with h5py.File(root / nyuv2.LABELLED_MAT, "a") as f:
        f.create_dataset("rawDepths", data=arrays["depth"].transpose(0, 2, 1) * 0.9)
    return {name: (root / name).read_bytes() for name in (nyuv2.LABELLED_MAT,
                                                           nyuv2.MAPPING_MAT)}


def test_fuzz_nyuv2_downloads(nyu_downloads, tmp_path):
    sample = dataclasses.replace(SAMPLES["nyuv2-samples"], expected=None,
                                 options={"frames": (1, 2), "depth": "raw"})
    files = {name: tmp_path / "cache" / name for name in nyu_downloads}
    for name, data in nyu_downloads.items():
        write_variant(files[name], data)
    base = tmp_path / "x"

    def run() -> None:
        shutil.rmtree(base, ignore_errors=True)
        (base / "out").mkdir(parents=True)
        (base / "work").mkdir()
        extract_sample(sample, files, base / "out", base / "work")

    @given(st.sampled_from(sorted(nyu_downloads)), st.data())
    def inner(name, data):
        for other, original in nyu_downloads.items():
            write_variant(files[other], original)
        mutated = data.draw(mutated_bytes(nyu_downloads[name]))
        write_variant(files[name], mutated)
        check_file("archives/nyuv2-downloads", run, files[name])

    inner()
