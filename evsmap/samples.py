"""The real sample data the tests and ``evsmap reproduce`` use, by name, and how each is made from
its official files.

Each sample is a small piece of a public dataset kept under the data root
(:func:`evsmap.paths.default_data_root`) in ``folder``; ``evsmap datasets fetch NAME`` makes it
from the official archive (:func:`evsmap.fetch.fetch_sample`): it downloads every
:class:`Source` (through pooch: :func:`evsmap.download.download`), runs the sample's extractor
(:data:`evsmap.sample_archives.EXTRACTORS`) into a staging folder and checks the result file by
file against the catalogue with the :class:`Rule` that applies to it:

``sha256``
    the file's bytes (files copied verbatim from the archive, or written deterministically);
``pixels``
    sha256 of the decoded image array (dtype, shape and values: :func:`array_digest`) - for
    images whose pixels are known exactly but whose PNG bytes depend on the encoder;
``mean-rgb-2x2``
    mean R, G, B of each quarter of a re-encoded (lossy) colour image, within ``tol`` levels;
``depth-stats``
    valid fraction, min, max and mean of a 16-bit depth image, each within its ``tol``.

The expected values (the data file ``evsmap/samples_expected.json``, read by
:mod:`evsmap.samples_expected`) were computed from the sample files of the shared data root with
``python -m evsmap.samples expected DATA_ROOT``; they are never typed in.
``dataclasses.replace(sample, expected=..., options=...)`` makes a variant, e.g. for tests with
tiny archives in the official layouts.
"""

from __future__ import annotations

import fnmatch
import hashlib
import io
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from evsmap.download import MANIFEST, FetchError, format_size, sha256_file
from evsmap.samples_expected import expected_for


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
    made: ``sources`` (downloads), ``extractor`` (a key of
    :data:`evsmap.sample_archives.EXTRACTORS`) with its ``options``, the ``rules`` saying which
    check applies to which file, the ``expected`` check values by relative path (``None``:
    nothing known, only the extraction runs) and ``checks``, the same in words.
    ``single_file``: ``folder`` names one file, not a folder."""

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


SAMPLES: dict[str, Sample] = {s.name: s for s in (
    Sample("tum-fr1-xyz", "tum_fr1_xyz",
           "TUM RGB-D freiburg1_xyz, first 1.2 s (37 RGB + 37 depth, full ground truth)",
           sources=(Source(TUM_URL, approx_size="", large=False),),
           extractor="tum",
           options={"sequence": "rgbd_dataset_freiburg1_xyz", "frames": 37},
           rules=(Rule("*", "sha256"),),
           expected=expected_for("tum-fr1-xyz"),
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
           expected=expected_for("sevenscenes-100"),
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
           expected=expected_for("nyuv2-samples"),
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
           expected=expected_for("lidar-odometry-bag"),
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


def write_expected_file(root: Path, out: Path | None = None) -> None:
    """Write the expected values (:mod:`evsmap.samples_expected`'s data file, or ``out``) from
    the samples under the data root ``root``."""
    from evsmap.samples_expected import DATA_FILE, write_expected

    write_expected({sample.name: compute_expected(sample, Path(root) / sample.folder)
                    for sample in SAMPLES.values()}, DATA_FILE if out is None else Path(out))


def _main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[0] != "expected":
        sys.stderr.write("usage: python -m evsmap.samples expected DATA_ROOT\n")
        return 2
    write_expected_file(Path(argv[1]))
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(_main(sys.argv[1:]))
