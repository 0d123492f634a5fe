"""What a run has to work with: where the data, weights and caches are, which sequences it maps,
and which requirements (datasets, weights, hardware) are satisfied on this machine."""

from __future__ import annotations

import os
import re
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from evsmap.paths import REPO_ROOT, default_data_root

SEGMENTATION_DATASETS = ("nyuv2", "sunrgbd", "cityscapes")
"""Datasets prepared with ``evsmap datasets prepare``, looked up as folders."""

MAPPING_SEQUENCES: dict[str, dict[str, Any]] = {
    # Table IV's Seq.1..5 (inferred, see paper_tables.toml) and where a user puts each: a TUM
    # folder, or a bag file / ROS2 bag folder read with the reader preset named here
    "tum": {"names": ("tum", "tum_fr1_xyz"), "reader": "tum", "options": {}},
    "rtabmap": {"names": ("rtabmap", "rtabmap.bag", "rtabmap_demo.bag"), "reader": "rosbag",
                "options": {"preset": "rtabmap"}},
    "asl": {"names": ("asl", "asl.bag", "cow_and_lady.bag", "data.bag"), "reader": "rosbag",
            "options": {"preset": "asl"}},
    "ours1": {"names": ("ours1", "ours1.bag"), "reader": "rosbag", "options": {"preset": "zed2i"}},
    "ours2": {"names": ("ours2", "ours2.bag"), "reader": "rosbag", "options": {"preset": "zed2i"}},
}


@dataclass
class RunContext:
    """Settings of one run, passed to every cell (picklable).

    Attributes:
        out: the run folder (records, artifacts, cache).
        data_root: where datasets and sequences are looked up (besides ``datasets/`` in the
            repository and ``../shared/data``).
        weights_dir: trained weights, ``<segmenter spec>@<dataset>.pt`` or
            ``<segmenter name>@<dataset>.pt``.
        quick: smoke-test settings (fewer frames and runs, smaller synthetic frames, torch
            backend for speed).
        synthetic: options of the built-in synthetic sequence.
        frames: frames mapped per sequence (None: all).
        speed_runs, speed_warmup, speed_backend, threads: the speed method.
        voxel_size: Table IV's voxel size (the paper's value is assumed: 5 cm).
    """

    out: str
    data_root: str | None = None
    weights_dir: str | None = None
    quick: bool = False
    synthetic: dict[str, Any] = field(default_factory=lambda: {
        "scene": "living_room", "seed": 0, "frames": 60, "width": 640, "height": 480,
        "noise": True})
    frames: int | None = None
    speed_runs: int = 10
    speed_warmup: int = 2
    speed_backend: str = "onnxruntime"
    threads: int = field(default_factory=lambda: os.cpu_count() or 1)
    voxel_size: float = 0.05
    oracle: dict[str, Any] = field(default_factory=lambda: {"seed": 0})

    @classmethod
    def create(cls, out: str | Path, *, data_root: str | Path | None = None,
               weights_dir: str | Path | None = None, quick: bool = False) -> RunContext:
        root = Path(data_root) if data_root else default_data_root()
        ctx = cls(out=str(out), data_root=str(root) if root else None,
                  weights_dir=str(weights_dir) if weights_dir else None, quick=quick)
        if quick:
            ctx.synthetic.update(frames=8, width=320, height=240)
            ctx.frames = 8
            ctx.speed_runs, ctx.speed_warmup, ctx.speed_backend = 3, 1, "torch"
        return ctx

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    # -- where things are -------------------------------------------------------------------
    def roots(self) -> list[Path]:
        roots = []
        if self.data_root:
            roots.append(Path(self.data_root))
        roots.append(REPO_ROOT / "datasets")
        roots.append(Path.cwd() / "datasets")
        seen, out = set(), []
        for r in roots:
            key = str(r.resolve()) if r.exists() else str(r)
            if key not in seen:
                seen.add(key)
                out.append(r)
        return out

    def dataset_path(self, name: str) -> Path | None:
        """The prepared dataset (or mapping sequence) ``name``, if present."""
        from evsmap.cli.info_cmd import detect_reader
        from evsmap.errors import EvsmapError

        names = MAPPING_SEQUENCES[name]["names"] if name in MAPPING_SEQUENCES else (name,)
        for root in self.roots():
            for n in names:
                path = root / n
                if not path.exists():
                    continue
                try:
                    detect_reader(path)
                except EvsmapError:
                    continue
                return path
        return None

    def weights_path(self, spec: str, dataset: str) -> Path | None:
        """``<spec>@<dataset>.pt`` (or ``<name>@<dataset>.pt``) in the weights folder."""
        if not self.weights_dir:
            return None
        folder = Path(self.weights_dir)
        name = re.sub(r"\(.*\)$", "", spec)
        for candidate in (f"{spec}@{dataset}", f"{name}@{dataset}"):
            for ext in (".pt", ".pth"):
                if (folder / (candidate + ext)).is_file():
                    return folder / (candidate + ext)
        return None

    def available(self, requires: list[str] | tuple[str, ...]) -> list[str]:
        """The requirements among ``requires`` that are satisfied here."""
        have = []
        for req in requires:
            kind, _, what = req.partition(":")
            if kind == "dataset" and self.dataset_path(what) is not None:
                have.append(req)
            elif kind == "weights":
                spec, _, dataset = what.rpartition("@")
                if self.weights_path(spec, dataset) is not None:
                    have.append(req)
            # hardware (a Jetson with TensorRT) is never available to this harness
        return have
