"""Checking a user's copy of ScanNet: what ``evsmap datasets check scannet`` reports.

ScanNet's terms of use need a signed agreement, so evsmap does not download it (:data:`OBTAIN`
says how to). A copy in the release layout (``scans/sceneNNNN_NN/`` with each scene's ``.sens``
and ``_vh_clean_2.labels.ply``, ``scannetv2-labels.combined.tsv`` and the split files beside
``scans/``) is checked file by file: present, readable, and the frame and vertex counts. Plain
records; the CLI formats them.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evsmap.errors import DataFormatError
from evsmap.readers.scannet.labelmap import (
    LABELS_TSV,
    SCENE_ID,
    SPLIT_FILE,
    SPLITS,
    read_label_table,
    read_split,
)
from evsmap.readers.scannet.reader import LABEL_ZIP_SUFFIX, MESH_SUFFIX

OBTAIN = (
    "ScanNet v2 is distributed under its terms of use, which need a signed agreement: fill in "
    "the form linked from http://www.scan-net.org/ (GitHub ScanNet/ScanNet, 'ScanNet Data'), "
    "and use the download script its authors send you, e.g. `download-scannet.py -o DIR "
    "--type .sens`, `--type _vh_clean_2.labels.ply` (and `--type _2d-label-filt.zip` for the "
    "2D labels). Put the release under the data root as scannet/ (scannet/scans/scene0011_00/"
    "..., scannet/scannetv2-labels.combined.tsv, and the split files scannetv2_val.txt etc. "
    "from ScanNet's Tasks/Benchmark), or pass --root DIR.")


@dataclass
class SceneCheck:
    """One scene: its counts, and the problems found (one line each)."""

    scene: str
    frames: int | None = None
    invalid_poses: int | None = None
    vertices: int | None = None
    faces: int | None = None
    label_images: bool = False
    problems: list[str] = field(default_factory=list)


@dataclass
class ReleaseCheck:
    """The whole copy."""

    root: str
    scenes: list[SceneCheck] = field(default_factory=list)
    splits: dict[str, int] = field(default_factory=dict)
    """Scenes listed per split file found."""
    split_present: dict[str, int] = field(default_factory=dict)
    """Of those, scenes present under ``scans/``."""
    label_table: bool = False
    problems: list[str] = field(default_factory=list)
    """Problems of the copy as a whole (not of one scene)."""

    def all_problems(self) -> list[str]:
        return self.problems + [p for s in self.scenes for p in s.problems]

    def as_dict(self) -> dict:
        from dataclasses import asdict

        return asdict(self)


def check_scene(folder: Path, *, meshes: bool = True) -> SceneCheck:
    """The scene folder's ``.sens`` (header and every frame's place) and labelled mesh."""
    from evsmap.readers.scannet.mesh import read_label_mesh
    from evsmap.readers.scannet.sens import SensFile

    out = SceneCheck(folder.name)
    sens = folder / f"{folder.name}.sens"
    if not sens.is_file():
        out.problems.append(f"{sens}: missing (the RGB-D stream)")
    else:
        try:
            stream = SensFile(sens)
            out.frames = len(stream)
            out.invalid_poses = sum(not np.all(np.isfinite(e.pose)) for e in stream.frames)
            if out.frames == 0:
                out.problems.append(f"{sens}: holds no frames")
        except DataFormatError as exc:
            out.problems.append(str(exc))
    mesh = folder / f"{folder.name}{MESH_SUFFIX}"
    if not mesh.is_file():
        out.problems.append(f"{mesh}: missing (the labelled mesh, the 3D ground truth)")
    elif meshes:
        try:
            m = read_label_mesh(mesh)
            out.vertices, out.faces = len(m.vertices), len(m.faces)
        except DataFormatError as exc:
            out.problems.append(str(exc))
    out.label_images = (folder / f"{folder.name}{LABEL_ZIP_SUFFIX}").is_file()
    return out


def check_release(root: Path, *, meshes: bool = True,
                  progress: Callable[[Iterable[Path]], Iterable[Path]] = lambda it: it
                  ) -> ReleaseCheck:
    """Every scene under ``root/scans`` (:func:`check_scene`), the label table and the split
    files."""
    out = ReleaseCheck(str(root))
    scans = root / "scans"
    table = root / LABELS_TSV
    if table.is_file():
        try:
            read_label_table(table)
            out.label_table = True
        except DataFormatError as exc:
            out.problems.append(str(exc))
    else:
        out.problems.append(f"{table}: missing (the ScanNet label ids' NYU40 classes, needed "
                            f"for the 2D label images)")
    folders = sorted(p for p in scans.iterdir() if p.is_dir() and SCENE_ID.match(p.name)) \
        if scans.is_dir() else []
    if not folders:
        out.problems.append(f"{scans}: no sceneNNNN_NN/ folders")
    present = {p.name for p in folders}
    for split in SPLITS:
        path = root / SPLIT_FILE.format(split)
        if not path.is_file():
            continue
        try:
            listed = read_split(path)
        except DataFormatError as exc:
            out.problems.append(str(exc))
            continue
        out.splits[split] = len(listed)
        out.split_present[split] = sum(s in present for s in listed)
    if "val" not in out.splits:
        out.problems.append(f"{root / SPLIT_FILE.format('val')}: missing (the validation split "
                            f"the runner's ScanNet section maps from; ScanNet's "
                            f"Tasks/Benchmark/scannetv2_val.txt)")
    out.scenes = [check_scene(f, meshes=meshes) for f in progress(folders)]
    return out


__all__ = ["OBTAIN", "ReleaseCheck", "SceneCheck", "check_release", "check_scene"]
