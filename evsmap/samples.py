"""The real sample data the tests and ``evsmap reproduce`` use, by name, and how each is made from
its official files.

Each sample is a small piece of a public dataset kept under the data root
(:func:`evsmap.paths.default_data_root`) in ``folder``; ``evsmap datasets fetch NAME`` makes it
from the official archive (:func:`evsmap.fetch.fetch_sample`): it downloads every
:class:`Source`, runs the sample's extractor (:data:`EXTRACTORS`) into a staging folder and checks
the result file by file against the catalogue with the :class:`Rule` that applies to it:

``sha256``
    the file's bytes (files copied verbatim from the archive, or written deterministically);
``pixels``
    sha256 of the decoded image array (dtype, shape and values: :func:`array_digest`) - for
    images whose pixels are known exactly but whose PNG bytes depend on the encoder;
``mean-rgb-2x2``
    mean R, G, B of each quarter of a re-encoded (lossy) colour image, within ``tol`` levels;
``depth-stats``
    valid fraction, min, max and mean of a 16-bit depth image, each within its ``tol``.

The expected values (:data:`evsmap.samples_expected.EXPECTED`) were computed from the sample
files of the shared data root with ``python -m evsmap.samples expected DATA_ROOT``; they are never
typed in. ``dataclasses.replace(sample, expected=..., options=...)`` makes a variant, e.g. for
tests with tiny archives in the official layouts.
"""

from __future__ import annotations

import fnmatch
import hashlib
import io
import os
import shutil
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from evsmap.download import (
    CHUNK,
    MANIFEST,
    CorruptArchiveError,
    FetchError,
    format_size,
    sha256_file,
)

Log = Callable[[str], None]


@dataclass(frozen=True)
class Source:
    """One file to download.

    ``size``/``sha256`` are checked when given: only figures computed from the real file or
    published by its maintainers go here. ``approx_size`` is a size as documented (for the listing
    and the prompt when the server does not say), ``large`` marks a multi-GB download that needs
    ``--yes`` even when its size cannot be asked.
    """

    url: str
    size: int | None = None
    sha256: str | None = None
    approx_size: str = ""
    large: bool = False
    filename: str = ""

    def __post_init__(self) -> None:
        if not self.filename:
            object.__setattr__(self, "filename", self.url.rstrip("/").rsplit("/", 1)[-1])


@dataclass(frozen=True)
class Rule:
    """The check for the files of a sample matching ``pattern`` (``fnmatch`` on the path relative
    to the sample folder): ``kind`` as in the module docstring, ``tol`` for the numeric kinds."""

    pattern: str
    kind: str
    tol: float | tuple[float, ...] = 0.0


@dataclass(frozen=True)
class Sample:
    """One sample: its name, its path under the data root, a one-line description and how it is
    made: ``sources`` (downloads), ``extractor`` (a key of :data:`EXTRACTORS`) with its
    ``options``, the ``rules`` saying which check applies to which file, the ``expected`` check
    values by relative path (``None``: nothing known, only the extraction runs) and ``checks``,
    the same in words. ``single_file``: ``folder`` names one file, not a folder."""

    name: str
    folder: str
    description: str
    sources: tuple[Source, ...] = ()
    extractor: str = ""
    options: Mapping[str, Any] = field(default_factory=dict)
    rules: tuple[Rule, ...] = ()
    expected: Mapping[str, Any] | None = None
    checks: str = ""
    single_file: bool = False
    homepage: str = ""
    licence: str = ""

    def rule_for(self, rel: str) -> Rule:
        for rule in self.rules:
            if fnmatch.fnmatchcase(rel, rule.pattern):
                return rule
        return Rule("*", "sha256")

    def size_text(self) -> str:
        """The download size as far as the catalogue knows it."""

        if self.sources and all(s.size is not None for s in self.sources):
            return format_size(sum(s.size for s in self.sources))  # type: ignore[misc]
        if any(s.size is None and not s.approx_size for s in self.sources):
            return "unknown"
        return " + ".join(f"about {s.approx_size}" if s.size is None else format_size(s.size)
                          for s in self.sources)


# -- the catalogue ------------------------------------------------------------------------------
TUM_URL = "https://cvg.cit.tum.de/rgbd/dataset/freiburg1/rgbd_dataset_freiburg1_xyz.tgz"
"""TUM RGB-D download page https://cvg.cit.tum.de/data/datasets/rgbd-dataset/download (fr1/xyz,
"tgz"). The archive holds ``rgbd_dataset_freiburg1_xyz/`` with ``rgb.txt``, ``depth.txt``,
``groundtruth.txt``, ``accelerometer.txt``, ``rgb/`` and ``depth/``. Its size is not
catalogued (no published byte count); the server's Content-Length is used and shown."""

SEVENSCENES_URL = ("https://download.microsoft.com/download/2/8/5/"
                   "28564B23-0828-408F-8631-23B1EFF1DAC8/redkitchen.zip")
"""Microsoft 7-Scenes, scene "RedKitchen" (project page
https://www.microsoft.com/en-us/research/project/rgb-d-dataset-7-scenes/; the per-scene zips live
under this download folder). The zip holds ``redkitchen/seq-NN.zip`` (one zip per sequence, each
with ``seq-NN/frame-NNNNNN.{color.png,depth.png,pose.txt}``) and the split files. Several GB; no
published byte count, so the server's Content-Length is used and ``--yes`` is always needed.

Which scene and sequence: the sample's first image shows red kitchen units and a wooden table
(RedKitchen), and its 100 camera poses agree with the published ``seq-01`` poses of RedKitchen
(``pgt/dslam/7scenes/redkitchen_train.txt`` of github.com/tsattler/visloc_pseudo_gt_limitations,
world-to-camera quaternions) to 0.005 in the quaternion and 2.2 cm, every frame, while every other
RedKitchen sequence is 0.2 m or more off - so ``seq-01``, frames 0-99. The pixel and pose checks
below confirm it on a real download."""

NYU_URL = "https://horatio.cs.nyu.edu/mit/silberman/nyu_depth_v2/nyu_depth_v2_labeled.mat"
"""NYU Depth v2 labelled set, linked from https://cs.nyu.edu/~silberman/datasets/nyu_depth_v2.html
("2.8 GB" on that page). No published byte count or checksum."""

NYU_MAPPING_URL = ("https://raw.githubusercontent.com/VainF/nyuv2-python-toolkit/"
                   "d883619ad796c8bff0f44eeaad17beb6f8e7b30a/classMapping40.mat")
"""The 894 -> 40 class mapping of Gupta et al. as in github.com/VainF/nyuv2-python-toolkit (the
copy ESANet's preparation uses; see datasets/README.md), pinned to the commit d883619 (the file
was added in 462702d and is unchanged since). Size and sha256 computed from that file."""

EMBAG_URL = ("https://raw.githubusercontent.com/embarktrucks/embag/"
             "74c0b5f9d50bd45bcb6ed8e44718cd60924c13d0/test/test.bag")
"""``test/test.bag`` of github.com/embarktrucks/embag (MIT), pinned to master at 74c0b5f (the
file is unchanged since 47bb1cb). Its size and sha256 are those of the shared sample
``ros/lidar_odometry.bag``, which is that file byte for byte (checked against the repository)."""


def _expected(name: str) -> Mapping[str, Any] | None:
    from evsmap.samples_expected import EXPECTED

    return EXPECTED.get(name)


SAMPLES: dict[str, Sample] = {s.name: s for s in (
    Sample("tum-fr1-xyz", "tum_fr1_xyz",
           "TUM RGB-D freiburg1_xyz, first 1.2 s (37 RGB + 37 depth, full ground truth)",
           sources=(Source(TUM_URL, approx_size="", large=False),),
           extractor="tum",
           options={"sequence": "rgbd_dataset_freiburg1_xyz", "frames": 37},
           rules=(Rule("*", "sha256"),),
           expected=_expected("tum-fr1-xyz"),
           checks="sha256 of every file: rgb/ and depth/ PNGs and groundtruth.txt verbatim from "
                  "the archive, rgb.txt and depth.txt the archive's files cut after their 37th "
                  "entry (header lines kept)",
           homepage="https://cvg.cit.tum.de/data/datasets/rgbd-dataset", licence="CC BY 4.0"),
    Sample("sevenscenes-100", "sevenscenes_100",
           "Microsoft 7-Scenes, first 100 frames of one sequence",
           sources=(Source(SEVENSCENES_URL, large=True),),
           extractor="sevenscenes",
           options={"scene": "redkitchen", "sequence": "seq-01", "frames": 100,
                    "jpeg_quality": 80, "intrinsics": (585.0, 585.0, 320.0, 240.0)},
           # jpeg_quality: the sample's JPEG quantisation tables are libjpeg's at quality 80
           # (4:2:0); intrinsics: fx = fy = 585, cx 320, cy 240 as on the 7-Scenes page
           rules=(Rule("*.color.jpg", "mean-rgb-2x2", 1.0), Rule("*.depth.png", "pixels"),
                  Rule("*.pose.txt", "sha256"), Rule("camera-intrinsics.txt", "sha256")),
           expected=_expected("sevenscenes-100"),
           checks="depth PNGs (copied verbatim): sha256 of the decoded pixels; pose.txt and "
                  "camera-intrinsics.txt (written with numpy '%.18e', deterministic): sha256; "
                  "colour: re-encoded PNG -> JPEG quality 80, so no file hash - the mean RGB of "
                  "each image quarter must match within 1.0",
           homepage="https://www.microsoft.com/en-us/research/project/rgb-d-dataset-7-scenes/",
           licence="Microsoft 7-Scenes licence, non-commercial research"),
    Sample("nyuv2-samples", "nyuv2_samples",
           "NYU Depth v2 labelled frames 000433 and 000464 (RGB, depth, 40-class labels)",
           sources=(Source(NYU_URL, approx_size="2.8 GB", large=True),
                    Source(NYU_MAPPING_URL, size=10474,
                           sha256="ff177194cce9a2163517f1e1e6f1c64c50987162f542dedddc04bbf6ebe6d851")),
           extractor="nyuv2",
           options={"frames": (433, 464), "depth": "raw"},
           rules=(Rule("rgb/*", "pixels"), Rule("label40/*", "pixels"),
                  Rule("depth/*", "depth-stats", (0.001, 1.0, 1.0, 1.0))),
           expected=_expected("nyuv2-samples"),
           checks="rgb/ and label40/: sha256 of the decoded pixels; depth/ (raw depth, "
                  "rawDepths): valid fraction (within 0.001), min, max and mean (within 1 = "
                  "0.2 mm) - the shared sample's PNGs were written by another tool whose "
                  "rounding is not known; classMapping40.mat: size and sha256",
           homepage="https://cs.nyu.edu/~silberman/datasets/nyu_depth_v2.html",
           licence="NYU Depth v2, research use"),
    Sample("lidar-odometry-bag", "ros/lidar_odometry.bag",
           "ROS1 bag with PointCloud2 and Odometry (embag test data)",
           sources=(Source(EMBAG_URL, size=3835840,
                           sha256="b6635cf0b7fa6ea8662ac464038ddd860c7021703b2fd9e11fcb324fb5860fd5"),),
           extractor="file",
           rules=(Rule("*", "sha256"),),
           expected=_expected("lidar-odometry-bag"),
           checks="size and sha256 of the bag (copied verbatim)",
           single_file=True,
           homepage="https://github.com/embarktrucks/embag", licence="MIT"),
)}


# -- checks -------------------------------------------------------------------------------------
def array_digest(array) -> str:
    """sha256 of an array's dtype, shape and values (little-endian, C order)."""
    import numpy as np

    a = np.ascontiguousarray(array)
    a = a.astype(a.dtype.newbyteorder("<"), copy=False)
    head = f"{a.dtype.str}:{'x'.join(str(n) for n in a.shape)}:".encode()
    return hashlib.sha256(head + a.tobytes()).hexdigest()


def _open_image(path: Path):
    """``path`` decoded with PIL (from memory: PIL reads what a damaged PNG chunk length claims
    in one call); an unreadable image, or one claiming more pixels than evsmap's readers take,
    is a :class:`FetchError`."""
    from PIL import Image, UnidentifiedImageError

    from evsmap.readers.images import MAX_PIXELS

    try:
        im = Image.open(io.BytesIO(path.read_bytes()))
        if im.width * im.height > MAX_PIXELS:
            raise FetchError(f"{path}: image header claims {im.width}x{im.height} pixels (at "
                             f"most {MAX_PIXELS} read; corrupt file?)")
        im.load()
    except UnidentifiedImageError:  # its message shows the in-memory buffer, not the file
        raise FetchError(f"{path}: unreadable image (not an image format PIL recognises)") \
            from None
    except (OSError, SyntaxError, ValueError, EOFError, Image.DecompressionBombError) as exc:
        raise FetchError(f"{path}: unreadable image ({' '.join(str(exc).split())})") from None
    return im


def _decode(path: Path):
    import numpy as np

    with _open_image(path) as im:
        if im.mode.startswith("I"):
            return np.asarray(im).astype("<u2")
        if im.mode not in ("RGB", "L"):
            im = im.convert("RGB")
        return np.asarray(im)


def compute_check(kind: str, path: Path) -> Any:
    """The value of check ``kind`` for the file ``path`` (see the module docstring); an image
    that cannot be decoded is a :class:`FetchError` naming it."""
    import numpy as np

    if kind == "sha256":
        return sha256_file(path)
    if kind == "pixels":
        return array_digest(_decode(path))
    if kind == "mean-rgb-2x2":
        with _open_image(path) as im:
            a = np.asarray(im.convert("RGB"), dtype=np.float64)
        h, w = a.shape[0] // 2, a.shape[1] // 2
        quarters = (a[:h, :w], a[:h, w:], a[h:, :w], a[h:, w:])
        return tuple(round(float(q[..., c].mean()), 3) for q in quarters for c in range(3))
    if kind == "depth-stats":
        d = _decode(path)
        valid = d[d > 0]
        if valid.size == 0:
            return (0.0, 0.0, 0.0, 0.0)
        return (round(valid.size / d.size, 6), float(valid.min()), float(valid.max()),
                round(float(valid.mean()), 3))
    raise ValueError(f"unknown check {kind!r}")


def check_matches(rule: Rule, expected: Any, actual: Any) -> bool:
    if rule.kind in ("sha256", "pixels"):
        return str(expected).lower() == str(actual).lower()
    exp, act = tuple(expected), tuple(actual)
    tol = rule.tol if isinstance(rule.tol, tuple) else (rule.tol,) * len(exp)
    return len(exp) == len(act) == len(tol) and all(
        abs(float(e) - float(a)) <= t + 1e-9 for e, a, t in zip(exp, act, tol, strict=True))


def _files(folder: Path) -> list[str]:

    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*")
                  if p.is_file() and not p.name.endswith(MANIFEST))


def verify_sample(sample: Sample, folder: Path, *, display: Path | None = None) -> list[dict]:
    """Check the files extracted into ``folder`` against ``sample.expected``; the manifest's file
    records (path, size, sha256, check). A missing, unexpected or differing file is a
    :class:`~evsmap.download.FetchError` naming it (under ``display``, the final path)."""

    shown = Path(display) if display is not None else Path(folder)
    if sample.single_file:
        shown = shown.parent
    produced = _files(folder)
    expected = sample.expected
    if expected is not None:
        missing = sorted(set(expected) - set(produced))
        if missing:
            raise FetchError(f"{shown / missing[0]}: not produced from the archive "
                             f"({len(missing)} expected files missing)")
        extra = sorted(set(produced) - set(expected))
        if extra:
            raise FetchError(f"{shown / extra[0]}: produced but not in the catalogue "
                             f"({len(extra)} unexpected files)")
    records = []
    for rel in produced:
        path = folder / rel
        digest = sha256_file(path)
        record: dict[str, Any] = {"path": rel, "size": path.stat().st_size, "sha256": digest}
        if expected is None:
            record["check"] = "none"
        else:
            rule = sample.rule_for(rel)
            try:
                value = digest if rule.kind == "sha256" else compute_check(rule.kind, path)
            except FetchError as exc:
                raise FetchError(str(exc).replace(str(path), str(shown / rel), 1) +
                                 f" ({rule.kind} check); nothing was written") from None
            if not check_matches(rule, expected[rel], value):
                raise FetchError(f"{shown / rel}: {rule.kind} check failed (got {_show(value)}, "
                                 f"expected {_show(expected[rel])}); nothing was written")
            record["check"] = rule.kind
        records.append(record)
    return records


def _show(value: Any) -> str:
    if isinstance(value, (tuple, list)):
        return "(" + ", ".join(f"{float(v):g}" for v in value) + ")"
    return str(value)


def compute_expected(sample: Sample, path: Path) -> dict[str, Any]:
    """The check values of the files of an existing copy of ``sample`` at ``path`` (its folder,
    or the file of a single-file sample), by relative path."""
    path = Path(path)
    if sample.single_file:
        return {path.name: compute_check(sample.rule_for(path.name).kind, path)}
    return {rel: compute_check(sample.rule_for(rel).kind, path / rel) for rel in _files(path)}


def write_expected_module(root: Path, out: Path) -> None:
    """Write :mod:`evsmap.samples_expected` from the samples under the data root ``root``."""
    lines = ['"""Expected check values of the samples (see :mod:`evsmap.samples`), by sample and',
             "relative path.", "",
             "Generated by ``python -m evsmap.samples expected DATA_ROOT`` from the real sample",
             "files of the shared data root; do not edit by hand.", '"""', "",
             "EXPECTED: dict[str, dict[str, str | tuple[float, ...]]] = {"]
    for sample in SAMPLES.values():
        values = compute_expected(sample, Path(root) / sample.folder)
        lines.append(f"    {sample.name!r}: {{")
        for rel, value in values.items():
            lines.append(f"        {rel!r}:")
            if isinstance(value, tuple) and len(repr(value)) > 86:
                items = [repr(v) for v in value]
                rows = [", ".join(items[i:i + 6]) for i in range(0, len(items), 6)]
                lines.append("            (" + ",\n             ".join(rows) + "),")
            else:
                lines.append(f"            {value!r},")
        lines.append("    },")
    lines.append("}")
    Path(out).write_text("\n".join(lines) + "\n")


# -- extraction ---------------------------------------------------------------------------------
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
                tarfile.open(fileobj=_BoundedReads(gz), mode="r:") as tf:  # type: ignore[call-overload]
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


def _main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[0] != "expected":
        sys.stderr.write("usage: python -m evsmap.samples expected DATA_ROOT\n")
        return 2
    write_expected_module(Path(argv[1]), Path(__file__).with_name("samples_expected.py"))
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(_main(sys.argv[1:]))
