"""How each sample is made from its official files: the extractors of
:data:`evsmap.samples.SAMPLES` (:data:`EXTRACTORS`, by the name in ``Sample.extractor``).

An extractor reads only the members a sample takes from the downloaded archives, each checked
first (a relative name that stays inside the output, a regular file, a plausible size: a damaged
or hostile archive is a :class:`~evsmap.download.CorruptArchiveError`), and writes the sample's
files into an empty folder: verbatim, cut (TUM's lists) or re-encoded (7-Scenes colour as JPEG,
poses through numpy, NYUv2 through :mod:`evsmap.datasets.nyuv2`). The result is then checked
against the catalogue by :func:`evsmap.samples.verify_sample`.
"""

from __future__ import annotations

import io
import os
import shutil
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from evsmap.download import CHUNK, CorruptArchiveError, FetchError, Log, format_size
from evsmap.samples import Sample

MAX_MEMBER_BYTES = 256 * 1024**2
"""The largest archive member (or tar header record) read into memory: far above any file a
sample takes from its archive (images, lists, poses), far below what a damaged header can
claim."""


def check_member_name(path: Path, name: str) -> str:
    """``name`` if it is a relative path that stays inside the folder an archive is unpacked to;
    an absolute name (``/x``, ``\\x``, ``C:x``) or one with a ``..`` component is refused: no
    evsmap code path may write or read outside its work folder because of an archive."""
    parts = name.replace("\\", "/").split("/")
    if name.startswith(("/", "\\")) or (len(name) > 1 and name[1] == ":") or ".." in parts \
            or "\0" in name:
        raise CorruptArchiveError(f"{path}: member {name!r} has an absolute path or a '..' "
                                  "component (refused: it would reach outside the extraction "
                                  "folder)", path)
    return name


def _zip_errors() -> tuple[type[BaseException], ...]:
    """What zipfile raises on a damaged archive: a bad directory or header, a truncated or
    corrupt member (zlib, lzma, CRC), an unknown compression method or encryption
    (NotImplementedError, RuntimeError), a name that does not decode (ValueError)."""
    import lzma
    import struct
    import zipfile
    import zlib

    return (zipfile.BadZipFile, zlib.error, lzma.LZMAError, struct.error, EOFError,
            NotImplementedError, RuntimeError, ValueError, OverflowError, KeyError)


def _writing_failed(exc: OSError) -> bool:
    """Whether an OSError met while unpacking is the output's (disk full, read-only, denied)
    rather than the archive's."""
    import errno

    return exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM)


class _ClaimTooLarge(Exception):
    """A tar header or member claims more than :data:`MAX_MEMBER_BYTES`."""


class _BoundedReads:
    """A file object whose ``read(n)`` refuses ``n`` above :data:`MAX_MEMBER_BYTES`: tarfile
    reads a header record or a member in one call of the size its header claims, and the
    decompressor allocates that size before reading."""

    def __init__(self, fileobj: Any) -> None:
        self._fileobj = fileobj

    def read(self, size: int | None = -1) -> bytes:
        if size is None or size < 0 or size > MAX_MEMBER_BYTES:
            raise _ClaimTooLarge(f"a header or member claims {size} bytes (more than "
                                 f"{format_size(MAX_MEMBER_BYTES)})")
        return self._fileobj.read(size)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._fileobj, name)


def _tar_kind(member: Any) -> str:
    if member.issym():
        return "a symbolic link"
    if member.islnk():
        return "a hard link"
    if member.isdir():
        return "a folder"
    if member.ischr() or member.isblk():
        return "a device"
    if member.isfifo():
        return "a FIFO"
    return "a special file"


def _read_tar_member(tf: Any, member: Any, path: Path) -> bytes:
    """The bytes of a regular-file member (links, devices and oversized members refused)."""
    if not member.isfile():
        raise CorruptArchiveError(f"{path}: member {member.name} is {_tar_kind(member)}, not a "
                                  "regular file", path)
    if member.size > MAX_MEMBER_BYTES:
        raise CorruptArchiveError(f"{path}: member {member.name} claims {member.size} bytes "
                                  f"(more than {format_size(MAX_MEMBER_BYTES)})", path)
    return tf.extractfile(member).read()


def _zip_kind(info: Any) -> str | None:
    """What a zip member is when it is not a regular file (Unix mode bits), else None."""
    import stat

    if info.is_dir():
        return "a folder"
    mode = info.external_attr >> 16
    if info.create_system != 3 or stat.S_IFMT(mode) in (0, stat.S_IFREG):
        return None  # no Unix file type recorded (as zipfile.writestr writes), or a file
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return "a special file"


def _check_zip_member(zf: Any, name: str, path: Path, where: str, *,
                      in_memory: bool = True) -> Any:
    """``zf``'s member ``name`` checked before it is read: a regular file whose claimed sizes
    are plausible (stored size within the archive, unpacked size within
    :data:`MAX_MEMBER_BYTES` when read into memory)."""
    info = zf.getinfo(name)
    kind = _zip_kind(info)
    if kind is not None:
        raise CorruptArchiveError(f"{path}: member {where} is {kind}, not a regular file", path)
    limit = Path(zf.filename).stat().st_size if zf.filename else None
    if limit is not None and info.compress_size > limit:
        raise CorruptArchiveError(f"{path}: member {where} claims {info.compress_size} stored "
                                  f"bytes, more than the archive holds", path)
    if in_memory and info.file_size > MAX_MEMBER_BYTES:
        raise CorruptArchiveError(f"{path}: member {where} claims {info.file_size} bytes (more "
                                  f"than {format_size(MAX_MEMBER_BYTES)})", path)
    return info


def _check_zip_names(zf: Any, path: Path) -> list[str]:
    names = zf.namelist()
    for name in names:
        check_member_name(path, name)
    return names


def extract_sample(sample: Sample, archives: Mapping[str, Path], out: Path, work: Path, *,
                   log: Log | None = None) -> None:
    """Run ``sample``'s extractor: read the downloaded ``archives`` (by source file name), write
    the sample's files into the empty folder ``out``; ``work`` is a scratch folder."""

    if sample.extractor not in EXTRACTORS:
        raise FetchError(f"sample {sample.name!r}: unknown extractor {sample.extractor!r}")
    EXTRACTORS[sample.extractor](sample, archives, Path(out), Path(work), log or (lambda _m: None))


def _archive(sample: Sample, archives: Mapping[str, Path], index: int = 0) -> Path:
    return Path(archives[sample.sources[index].filename])


def _frames(items: list, desc: str):
    from evsmap.progress import progress

    return progress(items, desc=desc, unit="file")


def _cut_list(raw: bytes, count: int, where: str) -> tuple[bytes, list[str]]:
    """The first ``count`` entries of a TUM ``rgb.txt``/``depth.txt`` with the comment lines before
    them: the file's bytes up to the end of the ``count``-th entry (without its line end), and
    the files those entries name."""

    kept: list[bytes] = []
    files: list[str] = []
    for line in raw.splitlines(keepends=True):
        text = line.decode("utf-8", "replace").strip()
        kept.append(line)
        if not text or text.startswith("#"):
            continue
        parts = text.split()
        if len(parts) != 2:
            raise FetchError(f"{where}: expected 'timestamp filename', got {text!r}")
        files.append(parts[1])
        if len(files) == count:
            return b"".join(kept).rstrip(b"\r\n"), files
    raise FetchError(f"{where}: {len(files)} entries, expected at least {count}")


def extract_tum(sample: Sample, archives: Mapping[str, Path], out: Path, work: Path,
                log: Log) -> None:
    """TUM RGB-D: the first ``frames`` RGB and depth images of ``sequence`` with ``rgb.txt`` and
    ``depth.txt`` cut to them, and the whole ``groundtruth.txt``, all verbatim.

    Every member name is checked (:func:`check_member_name`); the members taken must be regular
    files of plausible size, the images listed as ``rgb/<file>`` or ``depth/<file>``."""
    import gzip
    import tarfile
    import zlib

    path = _archive(sample, archives)
    prefix = f"{sample.options['sequence']}/"
    count = int(sample.options["frames"])
    texts: dict[str, bytes] = {}
    images: dict[str, tarfile.TarInfo] = {}
    try:
        with gzip.open(path, "rb") as gz, \
                tarfile.open(fileobj=_BoundedReads(gz), mode="r:") as tf:
            for member in tf:
                check_member_name(path, member.name)
                if not member.name.startswith(prefix):
                    continue
                rel = member.name[len(prefix):]
                if rel in ("rgb.txt", "depth.txt", "groundtruth.txt"):
                    texts[rel] = _read_tar_member(tf, member, path)
                elif rel.startswith(("rgb/", "depth/")):
                    images[rel] = member
            for name in ("rgb.txt", "depth.txt", "groundtruth.txt"):
                if name not in texts:
                    raise FetchError(f"{path}: has no member {prefix}{name} (expected the "
                                     f"{prefix.rstrip('/')} archive)")
            wanted: list[str] = []
            for name in ("rgb.txt", "depth.txt"):
                cut, files = _cut_list(texts[name], count, f"{path}:{prefix}{name}")
                for rel in files:
                    if rel.count("/") != 1 or rel.split("/")[0] != name[:-4] or rel.endswith("/"):
                        raise FetchError(f"{path}:{prefix}{name}: lists {rel!r}, expected "
                                         f"{name[:-4]}/<file>")
                (out / name).write_bytes(cut)
                wanted += files
            (out / "groundtruth.txt").write_bytes(texts["groundtruth.txt"])
            for rel in wanted:
                if rel not in images:
                    raise FetchError(f"{path}: has no member {prefix}{rel} (listed in "
                                     f"{rel.split('/')[0]}.txt)")
            (out / "rgb").mkdir()
            (out / "depth").mkdir()
            ordered = sorted(wanted, key=lambda r: images[r].offset_data)
            for rel in _frames(ordered, f"extracting {sample.name}"):
                (out / rel).write_bytes(_read_tar_member(tf, images[rel], path))
    except (tarfile.TarError, EOFError, zlib.error, gzip.BadGzipFile, _ClaimTooLarge) as exc:
        raise CorruptArchiveError(f"{path}: not a readable .tgz archive ({exc})", path) from None


def _zip_members(zf, suffix: str) -> dict[str, str]:
    """Member names of ``zf`` by their last path component, for names ending in ``suffix``."""
    return {n.rsplit("/", 1)[-1]: n for n in zf.namelist() if n.endswith(suffix)}


def extract_sevenscenes(sample: Sample, archives: Mapping[str, Path], out: Path, work: Path,
                        log: Log) -> None:
    """7-Scenes: frames ``0 .. frames-1`` of ``scene/sequence``: the colour PNG re-encoded as JPEG
    (``jpeg_quality``), the depth PNG verbatim, the pose re-written with numpy (``%.18e``), and
    ``camera-intrinsics.txt`` (the published K).

    Every member name of both zips is checked (:func:`check_member_name`); the members taken
    must be regular files whose claimed sizes are plausible."""
    import zipfile

    import numpy as np
    from PIL import Image, UnidentifiedImageError

    path = _archive(sample, archives)
    scene, seq = sample.options["scene"], sample.options["sequence"]
    count = int(sample.options["frames"])
    quality = int(sample.options["jpeg_quality"])
    fx, fy, cx, cy = (float(v) for v in sample.options["intrinsics"])
    inner_path = work / f"{seq}.zip"
    try:
        with zipfile.ZipFile(path) as outer:
            names = [n for n in _check_zip_names(outer, path)
                     if n in (f"{scene}/{seq}.zip", f"{seq}.zip") or n.endswith(f"/{seq}.zip")]
            if not names:
                raise FetchError(f"{path}: has no member {scene}/{seq}.zip (expected the 7-Scenes "
                                 f"{scene} archive)")
            _check_zip_member(outer, names[0], path, names[0], in_memory=False)
            log(f"  unpacking {names[0]}")
            with outer.open(names[0]) as src, open(inner_path, "wb") as dst:
                shutil.copyfileobj(src, dst, CHUNK)
        with zipfile.ZipFile(inner_path) as inner:
            _check_zip_names(inner, path)
            members = _zip_members(inner, "")

            def read(stem: str, suffix: str) -> bytes:
                name = members[stem + suffix]
                _check_zip_member(inner, name, path, f"{seq}.zip:{name}")
                return inner.read(name)

            for i in _frames(list(range(count)), f"extracting {sample.name}"):
                stem = f"frame-{i:06d}"
                for suffix in (".color.png", ".depth.png", ".pose.txt"):
                    if stem + suffix not in members:
                        raise FetchError(f"{path}: {seq}.zip has no member "
                                         f"{seq}/{stem}{suffix}")
                where = f"{path}:{seq}/{stem}"
                try:
                    with Image.open(io.BytesIO(read(stem, ".color.png"))) as im:
                        rgb = im.convert("RGB")
                        rgb.save(out / f"{stem}.color.jpg", format="JPEG", quality=quality)
                except (UnidentifiedImageError, OSError, SyntaxError, ValueError,
                        Image.DecompressionBombError) as exc:
                    raise FetchError(f"{where}.color.png: unreadable image ({exc})") from None
                (out / f"{stem}.depth.png").write_bytes(read(stem, ".depth.png"))
                text = read(stem, ".pose.txt").decode("utf-8", "replace")
                try:
                    pose = np.loadtxt(io.StringIO(text), dtype=np.float64)
                except ValueError as exc:
                    raise FetchError(f"{where}.pose.txt: not a 4x4 matrix "
                                     f"({' '.join(str(exc).split())})") from None
                if pose.shape != (4, 4):
                    raise FetchError(f"{where}.pose.txt: not a 4x4 matrix (shape {pose.shape})")
                np.savetxt(out / f"{stem}.pose.txt", pose)
    except _zip_errors() as exc:
        raise CorruptArchiveError(f"{path}: not a readable zip archive "
                                  f"({type(exc).__name__}: {exc})", path) from None
    except OSError as exc:  # a seek or read the damaged directory sends astray
        if _writing_failed(exc):
            raise FetchError(f"{out}: cannot write the sample ({exc})") from None
        raise CorruptArchiveError(f"{path}: not a readable zip archive ({exc})", path) from None
    finally:
        inner_path.unlink(missing_ok=True)
    k = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    np.savetxt(out / "camera-intrinsics.txt", k)


def extract_nyuv2(sample: Sample, archives: Mapping[str, Path], out: Path, work: Path,
                  log: Log) -> None:
    """NYUv2: the labelled ``frames`` (1-based) through :func:`evsmap.datasets.nyuv2.prepare_nyuv2`
    (rgb/, depth/, label40/ only: the sample keeps no split lists or manifest).

    With ``depth="raw"`` (the default) depth/ then holds the raw depth (``rawDepths``) instead of
    the in-painted one: the shared sample's depth PNGs have the raw maps' holes and black border
    (a third of the pixels are 0), whatever its README says."""
    import numpy as np
    import scipy.io

    from evsmap.datasets import nyuv2
    from evsmap.errors import EvsmapError

    labelled = _archive(sample, archives, 0)
    mapping = _archive(sample, archives, 1)
    frames = sorted(int(f) for f in sample.options["frames"])
    if len(frames) < 2:
        raise FetchError(f"sample {sample.name!r}: needs at least two frames")
    src = work / "source"
    src.mkdir()
    _link(labelled, src / nyuv2.LABELLED_MAT)
    shutil.copyfile(mapping, src / nyuv2.MAPPING_MAT)
    # prepare_nyuv2 reads the split file to choose its frames: a stand-in holding just ours (the
    # official splits.mat is not needed, the sample keeps no split lists)
    scipy.io.savemat(src / nyuv2.SPLITS_MAT, {
        "trainNdxs": np.array([[frames[0]]], dtype=np.float64),
        "testNdxs": np.array([[f] for f in frames[1:]], dtype=np.float64)})
    prepared = work / "prepared"
    try:
        nyuv2.prepare_nyuv2(src, prepared, progress=lambda items: _frames(
            list(items), f"extracting {sample.name}"))
    except EvsmapError as exc:
        message = str(exc).replace(str(src / nyuv2.LABELLED_MAT), str(labelled)) \
            .replace(str(src / nyuv2.MAPPING_MAT), str(mapping))
        raise FetchError(message) from None
    for sub in (nyuv2.RGB_DIR, nyuv2.DEPTH_DIR, nyuv2.LABEL_DIR):
        (out / sub).mkdir()
        for f in frames:
            name = f"{f:06d}.png"
            (prepared / sub / name).replace(out / sub / name)
    if sample.options.get("depth", "raw") == "raw":
        _write_raw_depth(labelled, frames, out / nyuv2.DEPTH_DIR)


def _write_raw_depth(labelled: Path, frames: list[int], folder: Path) -> None:
    """Replace the in-painted depth that ``prepare_nyuv2`` writes by the raw depth
    (``rawDepths``: metres, 0 where the Kinect gave none), quantised the same way (value / 5000
    m, 0 invalid or beyond the 16-bit range)."""
    import h5py
    import numpy as np

    from evsmap.datasets import nyuv2
    from evsmap.datasets.common import H5_ERRORS
    from evsmap.readers.images import write_png

    try:
        with h5py.File(labelled, "r") as f:
            if "rawDepths" not in f:
                raise FetchError(f"{labelled}: has no dataset 'rawDepths' (expected the labelled "
                                 "NYUv2 set)")
            raw = f["rawDepths"]
            if not isinstance(raw, h5py.Dataset) or raw.dtype.kind not in "uif" \
                    or raw.shape[1:] != (nyuv2.WIDTH, nyuv2.HEIGHT) or raw.shape[0] < frames[-1]:
                raise FetchError(f"{labelled}: rawDepths is not N x {nyuv2.WIDTH} x "
                                 f"{nyuv2.HEIGHT} numbers with N >= {frames[-1]}")
            for index in frames:
                metres = np.asarray(raw[index - 1], dtype=np.float64).T
                ok = np.isfinite(metres) & (metres > 0)
                q = np.where(ok, np.round(np.where(ok, metres, 0.0) * nyuv2.DEPTH_SCALE), 0.0)
                depth = np.where(q > 65535, 0, q).astype(np.uint16)
                write_png(folder / f"{index:06d}.png", depth)
    except H5_ERRORS as exc:
        raise FetchError(f"{labelled}: cannot read rawDepths ({exc})") from None


def _link(src: Path, dst: Path) -> None:
    """``dst`` pointing at ``src`` (symlink, else hard link, else a copy)."""
    for make in (os.symlink, os.link):
        try:
            make(Path(src).resolve(), dst)
            return
        except OSError:
            continue
    shutil.copyfile(src, dst)


def extract_file(sample: Sample, archives: Mapping[str, Path], out: Path, work: Path,
                 log: Log) -> None:
    """A single file, copied verbatim under the sample's file name."""
    shutil.copyfile(_archive(sample, archives), out / Path(sample.folder).name)


EXTRACTORS: dict[str, Callable[[Sample, Mapping[str, Path], Path, Path, Log], None]] = {
    "tum": extract_tum, "sevenscenes": extract_sevenscenes, "nyuv2": extract_nyuv2,
    "file": extract_file,
}
"""Extractors by name: ``(sample, archives by file name, out folder, scratch folder, log)``."""

