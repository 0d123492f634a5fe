"""Builders of tiny copies of the official NYUv2, SUN RGB-D and Cityscapes files, written in
exactly their original structures (MATLAB v5 through scipy, MATLAB v7.3 = HDF5 with a MATLAB
user block and object references through h5py, PNG/JPEG/JSON trees)."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import scipy.io
from PIL import Image

from evsmap.datasets import cityscapes as cs
from evsmap.datasets import nyuv2


def write_png(path: Path, array: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(array).save(path, format="PNG", compress_level=1)


def h5_matlab(path: Path) -> h5py.File:
    """An HDF5 file with MATLAB's 512-byte user block (the header is written on close)."""
    return h5py.File(path, "w", userblock_size=512)


def stamp_matlab_header(path: Path) -> None:
    text = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 " \
           b"HDF5 schema 1.00 ."
    header = text.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02" + b"IM"
    with open(path, "r+b") as f:
        f.write(header)


# -- NYUv2 ------------------------------------------------------------------------------------
NYU_TRAIN = [1, 3, 4]
NYU_TEST = [2, 5]


def nyu_arrays(n: int = 5) -> dict[str, np.ndarray]:
    """Per-frame HxW(x3) arrays as MATLAB shows them (row = y)."""
    h, w = nyuv2.HEIGHT, nyuv2.WIDTH
    y, x = np.mgrid[0:h, 0:w]
    rgb, depth, labels = [], [], []
    for k in range(n):
        img = np.stack([x % 256, y % 256, np.full_like(x, 40 * k)], axis=2).astype(np.uint8)
        img[:10, :20] = 255  # a bright block in the top-left corner only
        rgb.append(img)
        d = (0.5 + x / w * 4.0 + y / h * 2.0 + 0.1 * k).astype(np.float32)
        d[:, :8] = 0.0  # invalid border
        d[h - 1, w - 1] = 20.0  # beyond the 16-bit range at 1/5000 m
        depth.append(d)
        lab = ((x // 8 + y // 8 * 80 + 17 * k) % 895).astype(np.uint16)  # 0 = void .. 894
        labels.append(lab)
    return {"rgb": np.stack(rgb), "depth": np.stack(depth), "labels": np.stack(labels)}


def nyu_map_class() -> np.ndarray:
    return (np.arange(894) * 7 % 40 + 1).astype(np.float64)  # source class k+1 -> 1..40


def write_nyu_source(root: Path, arrays: dict[str, np.ndarray] | None = None, *,
                     transposed_wrong: bool = False) -> dict[str, np.ndarray]:
    arrays = arrays if arrays is not None else nyu_arrays()
    root.mkdir(parents=True, exist_ok=True)
    mat = root / nyuv2.LABELLED_MAT
    with h5_matlab(mat) as f:
        images = arrays["rgb"].transpose(0, 3, 2, 1)  # MATLAB 480x640x3xN, column-major
        if transposed_wrong:
            images = arrays["rgb"].transpose(0, 3, 1, 2)
        f.create_dataset("images", data=images)
        f.create_dataset("depths", data=arrays["depth"].transpose(0, 2, 1))
        f.create_dataset("labels", data=arrays["labels"].transpose(0, 2, 1))
        f.create_dataset("names", data=np.zeros((1, 894), dtype=np.uint64))
    stamp_matlab_header(mat)
    scipy.io.savemat(root / nyuv2.SPLITS_MAT, {
        "trainNdxs": np.array(NYU_TRAIN, dtype=np.float64)[:, None],
        "testNdxs": np.array(NYU_TEST, dtype=np.float64)[:, None]})
    scipy.io.savemat(root / nyuv2.MAPPING_MAT, {
        "mapClass": nyu_map_class()[None, :],
        "className": np.array([[f"c{i}" for i in range(40)]], dtype=object)})
    return arrays


# -- SUN RGB-D ----------------------------------------------------------------------------------
SUN_PREFIX = "/n/fs/sun3d/data/SUNRGBD/"
# (scene, (width, height), split, K)
SUN_FRAMES = [
    ("kv1/NYUdata/NYU0001", (16, 12), "train", (10.0, 11.0, 7.5, 5.5)),
    ("kv1/NYUdata/NYU0002", (16, 12), "test", (10.0, 11.0, 7.5, 5.5)),
    ("kv2/kinect2data/000001_2014-05-26_14-23-37_rgbf000103-resize", (20, 10), "train",
     (12.0, 12.5, 9.0, 4.0)),
    ("realsense/lg/2014_10_24-13_59_50-1311000073", (20, 10), "test", (14.0, 14.0, 10.0, 5.0)),
    ("xtion/sun_data/2014_x", (18, 14), "train", (13.0, 13.5, 8.0, 6.5)),
]


def sun_encode(mm: np.ndarray) -> np.ndarray:
    """Millimetres -> SUN RGB-D depth PNG values (rotated left by 3 bits on 16 bits)."""
    v = mm.astype(np.uint32)
    return (((v << 3) | (v >> 13)) & 0xFFFF).astype(np.uint16)


def write_sun_source(root: Path) -> dict:
    """The official tree for SUN_FRAMES; returns the arrays per frame index."""
    data = root / "SUNRGBD"
    truth = []
    meta = np.zeros((1, len(SUN_FRAMES)), dtype=[("sequenceName", "O"), ("rgbpath", "O"),
                                                   ("rgbname", "O"), ("depthname", "O"),
                                                   ("K", "O")])
    labels = []
    for i, (scene, (w, h), _split, (fx, fy, cx, cy)) in enumerate(SUN_FRAMES):
        folder = data / scene
        y, x = np.mgrid[0:h, 0:w]
        rgb = np.stack([x * 12 % 256, y * 20 % 256, np.full_like(x, 30 * i)], 2).astype(np.uint8)
        name = f"img_{i:04d}"
        (folder / "image").mkdir(parents=True)
        Image.fromarray(rgb).save(folder / "image" / f"{name}.jpg", quality=95)
        mm = (800 + 37 * x + 101 * y + 5 * i).astype(np.uint16)
        mm[0, 0] = 0
        mm[-1, -1] = 9000  # beyond 8 m: kept (the toolbox clamps for point clouds only)
        write_png(folder / "depth_bfx" / f"{name}.png", sun_encode(mm))
        write_png(folder / "depth" / f"{name}.png", sun_encode(mm // 2))
        (folder / "intrinsics.txt").write_text(
            f"{fx} 0 {cx}\n0 {fy} {cy}\n0 0 1\n")
        lab = ((x + 3 * y + i) % 38).astype(np.float64)  # 0 = void, 1..37
        labels.append(lab)
        meta[0, i] = (scene, f"{SUN_PREFIX}{scene}/image/{name}.jpg", f"{name}.jpg",
                      f"{name}.png", np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]))
        truth.append({"rgb_path": folder / "image" / f"{name}.jpg", "mm": mm, "labels": lab,
                      "K": (fx, fy, cx, cy), "size": (w, h), "scene": scene})
    meta_dir = root / "SUNRGBDtoolbox" / "Metadata"
    meta_dir.mkdir(parents=True)
    scipy.io.savemat(meta_dir / "SUNRGBDMeta.mat", {"SUNRGBDMeta": meta})
    seg = meta_dir / "SUNRGBD2Dseg.mat"
    with h5_matlab(seg) as f:
        refs_group = f.create_group("#refs#")
        refs = np.empty((len(labels), 1), dtype=h5py.ref_dtype)
        for i, lab in enumerate(labels):
            ds = refs_group.create_dataset(f"r{i}", data=lab.T)  # MATLAB HxW, column-major
            refs[i, 0] = ds.ref
        group = f.create_group("SUNRGBD2Dseg")
        group.create_dataset("seglabel", data=refs, dtype=h5py.ref_dtype)
    stamp_matlab_header(seg)
    split_dir = root / "SUNRGBDtoolbox" / "traintestSUNRGBD"
    split_dir.mkdir(parents=True)
    train = [SUN_PREFIX + s for s, _, sp, _ in SUN_FRAMES if sp == "train"]
    test = [SUN_PREFIX + s for s, _, sp, _ in SUN_FRAMES if sp == "test"]
    train[0] += "/"  # a trailing slash must not matter
    scipy.io.savemat(split_dir / "allsplit.mat", {
        "alltrain": np.array([train], dtype=object), "alltest": np.array([test], dtype=object)})
    return {"frames": truth}


# -- Cityscapes ---------------------------------------------------------------------------------
W, H = cs.NATIVE_WIDTH, cs.NATIVE_HEIGHT
CITY_FRAMES = {
    "train": [("aachen", "aachen_000000_000019"), ("bochum", "bochum_000000_000313")],
    "val": [("frankfurt", "frankfurt_000000_000294")],
    "test": [("berlin", "berlin_000000_000019")],
}


def city_camera(k: int) -> dict:
    return {"extrinsic": {"baseline": 0.209313 + 0.001 * k, "pitch": 0.038, "roll": 0.0,
                          "x": 1.7, "y": 0.1, "yaw": -0.0195, "z": 1.3},
            "intrinsic": {"fx": 2262.52 + k, "fy": 2265.30, "u0": 1096.98, "v0": 513.137}}


def city_arrays(k: int) -> dict[str, np.ndarray]:
    y = np.arange(H)[:, None]
    x = np.arange(W)[None, :]
    rgb = np.empty((H, W, 3), dtype=np.uint8)
    rgb[..., 0] = (x + 3 * y) % 256
    rgb[..., 1] = (x // 3 + y) % 256
    rgb[..., 2] = 20 * k
    ids = np.broadcast_to(((x // 60) % 34).astype(np.uint8), (H, W)).copy()  # every id 0..33
    disp = np.broadcast_to((1 + 256 * (1 + (x // 64) % 40)).astype(np.uint16), (H, W)).copy()
    disp[:, :64] = 0  # invalid
    disp[:10, 64:128] = 1  # zero disparity: invalid too
    return {"rgb": rgb, "ids": ids, "disp": disp}


def write_city_tree(root: Path, frames: dict[str, list[tuple[str, str]]] | None = None, *,
                    test_labels: bool = True) -> dict[str, dict[str, np.ndarray]]:
    frames = CITY_FRAMES if frames is None else frames
    truth = {}
    k = 0
    for split, items in frames.items():
        for city, stem in items:
            a = city_arrays(k)
            rel = Path(split, city)
            write_png(root / "leftImg8bit" / rel / f"{stem}_leftImg8bit.png", a["rgb"])
            if split != "test" or test_labels:
                ids = a["ids"] if split != "test" else np.zeros((H, W), np.uint8)
                write_png(root / "gtFine" / rel / f"{stem}_gtFine_labelIds.png", ids)
            write_png(root / "disparity" / rel / f"{stem}_disparity.png", a["disp"])
            cam = root / "camera" / rel / f"{stem}_camera.json"
            cam.parent.mkdir(parents=True, exist_ok=True)
            cam.write_text(json.dumps(city_camera(k)))
            truth[f"{split}/{stem}"] = {**a, "camera": city_camera(k)}
            k += 1
    return truth
