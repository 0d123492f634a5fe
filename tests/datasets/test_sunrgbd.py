import json
import shutil

import h5py
import numpy as np
import pytest
import scipy.io
from datasets_fixtures import SUN_FRAMES, sun_encode
from PIL import Image

from evsmap.classes import SUNRGBD37_CLASSES
from evsmap.data import Intrinsics
from evsmap.datasets.common import MANIFEST
from evsmap.datasets.sunrgbd import (
    SUNRGBDSequence,
    decode_depth,
    is_sunrgbd_folder,
    prepare_sunrgbd,
    scene_key,
)
from evsmap.errors import DataFormatError, EvsmapError, InvalidDataError
from evsmap.registry import READERS


def test_depth_bit_rotation_round_trips():
    mm = np.arange(65536, dtype=np.uint32).astype(np.uint16)
    assert np.array_equal(decode_depth(sun_encode(mm)), mm)
    # the toolbox: bitor(bitshift(v, -3), bitshift(v, 16 - 3)) on uint16 (bits shifted out are lost)
    v = np.array([0, 8, 8000, 0x0001, 0xFFFF], dtype=np.uint16)
    assert decode_depth(v).tolist() == [0, 1, 1000, 0x2000, 0xFFFF]


def test_scene_key():
    assert scene_key("/n/fs/sun3d/data/SUNRGBD/kv1/NYUdata/NYU0001/") == "kv1/NYUdata/NYU0001"
    assert scene_key("SUNRGBD/kv2/a/b") == "kv2/a/b"
    assert scene_key("/elsewhere/kv1/x") is None


def test_prepare_round_trip(sun_source, tmp_path):
    src, truth = sun_source
    out = tmp_path / "sunrgbd"
    manifest = prepare_sunrgbd(src, out)
    assert is_sunrgbd_folder(out) and json.loads((out / MANIFEST).read_text()) == manifest
    assert manifest["splits"] == {"train": 3, "test": 2} and manifest["unlisted_in_allsplit"] == 0
    assert manifest["depth_source"] == "depth_bfx" and manifest["source_frames"] == 5
    seq = READERS.create("sunrgbd", path=str(out))
    assert seq.names == ["train/00001", "train/00002", "train/00003", "test/00001", "test/00002"]
    # SUNRGBDMeta order within each split
    order = {"train": [0, 2, 4], "test": [1, 3]}
    expected = [order["train"][0], order["train"][1], order["train"][2], *order["test"]]
    assert seq.meta["poses"] is False and seq.meta["layout"] == "sunrgbd"
    assert seq.meta["class_names"] == list(SUNRGBD37_CLASSES) and seq.meta["num_classes"] == 37
    assert seq.meta["sizes"] == ["16x12", "18x14", "20x10"]
    assert seq.intrinsics == Intrinsics(10.0, 11.0, 7.5, 5.5, 16, 12)  # the first frame's
    for frame, k in zip(seq, expected, strict=True):
        t = truth["frames"][k]
        fx, fy, cx, cy = t["K"]
        assert frame.intrinsics == Intrinsics(fx, fy, cx, cy, *t["size"])
        assert frame.rgb.shape == (t["size"][1], t["size"][0], 3)
        assert np.array_equal(frame.rgb, np.asarray(Image.open(t["rgb_path"]).convert("RGB")))
        assert np.allclose(frame.depth, t["mm"] / 1000.0)
        assert frame.depth[0, 0] == 0 and frame.depth[-1, -1] == pytest.approx(9.0)
        lut = np.concatenate([[255], np.arange(37)])
        assert np.array_equal(frame.labels, lut[t["labels"].astype(int)])
        assert np.array_equal(frame.pose, np.eye(4))
    rows = (out / "train" / "frames.txt").read_text().splitlines()
    assert rows[1].split()[-1] == SUN_FRAMES[0][0]
    assert len(SUNRGBDSequence(path=out, split="test")) == 2
    assert len(SUNRGBDSequence(path=out, split="train", limit=2)) == 2


def test_prepare_raw_depth_and_limit(sun_source, tmp_path):
    src, truth = sun_source
    manifest = prepare_sunrgbd(src, tmp_path / "o", limit=1, raw_depth=True)
    assert manifest["splits"] == {"train": 1, "test": 1} and manifest["depth_source"] == "depth"
    seq = SUNRGBDSequence(path=tmp_path / "o")
    assert np.allclose(seq[0].depth, (truth["frames"][0]["mm"] // 2) / 1000.0)
    assert np.allclose(seq[1].depth, (truth["frames"][1]["mm"] // 2) / 1000.0)


def test_unlisted_frames_go_to_test(sun_source, tmp_path):
    src, _ = sun_source
    split = src / "SUNRGBDtoolbox" / "traintestSUNRGBD" / "allsplit.mat"
    scipy.io.savemat(split, {"alltrain": np.array([["/n/fs/sun3d/data/SUNRGBD/" +
                                                     SUN_FRAMES[0][0]]], dtype=object),
                             "alltest": np.array([["/n/fs/sun3d/data/SUNRGBD/" +
                                                    SUN_FRAMES[1][0]]], dtype=object)})
    manifest = prepare_sunrgbd(src, tmp_path / "o")
    assert manifest["splits"] == {"train": 1, "test": 4} and manifest["unlisted_in_allsplit"] == 3


def test_prepare_errors_name_the_file(sun_source, tmp_path):
    src, truth = sun_source
    (src / "SUNRGBD" / SUN_FRAMES[3][0] / "depth_bfx" / "img_0003.png").unlink()
    with pytest.raises(DataFormatError) as err:
        prepare_sunrgbd(src, tmp_path / "o")
    assert str(err.value) == (f"{src / 'SUNRGBD' / SUN_FRAMES[3][0] / 'depth_bfx' / 'img_0003.png'}"
                              ": depth image not found (listed by SUNRGBDMeta(4) in "
                              "SUNRGBDMeta.mat)")
    assert not (tmp_path / "o").exists()

    (src / "SUNRGBD" / SUN_FRAMES[2][0] / "intrinsics.txt").write_text("1 2 3\n")
    with pytest.raises(DataFormatError, match=r"intrinsics\.txt: expected 9 numbers"):
        prepare_sunrgbd(src, tmp_path / "o", limit=2)

    seg = src / "SUNRGBDtoolbox" / "Metadata" / "SUNRGBD2Dseg.mat"
    with h5py.File(seg, "r+") as f:
        f["#refs#"]["r0"][0, 0] = 40.0
    with pytest.raises(DataFormatError, match=r"SUNRGBD2Dseg\.mat: SUNRGBD2Dseg\(1\)\.seglabel: "
                                              r"labels must be integers in 0..37"):
        prepare_sunrgbd(src, tmp_path / "o", limit=1)

    shutil.rmtree(src / "SUNRGBDtoolbox" / "traintestSUNRGBD")
    with pytest.raises(DataFormatError, match=r"allsplit\.mat: SUN RGB-D split not found"):
        prepare_sunrgbd(src, tmp_path / "o")


def test_seglabel_count_must_match_meta(sun_source, tmp_path):
    src, _ = sun_source
    seg = src / "SUNRGBDtoolbox" / "Metadata" / "SUNRGBD2Dseg.mat"
    with h5py.File(seg, "r+") as f:
        refs = f["SUNRGBD2Dseg"]["seglabel"][()]
        del f["SUNRGBD2Dseg"]["seglabel"]
        f["SUNRGBD2Dseg"].create_dataset("seglabel", data=refs[:3], dtype=h5py.ref_dtype)
    with pytest.raises(DataFormatError, match="3 label images but SUNRGBDMeta.mat lists 5"):
        prepare_sunrgbd(src, tmp_path / "o")


def test_bad_prepared_frames(sun_source, tmp_path):
    out = tmp_path / "sun"
    prepare_sunrgbd(sun_source[0], out)
    Image.fromarray(np.zeros((12, 16), np.uint8)).save(out / "train" / "depth" / "00001.png")
    Image.fromarray(np.zeros((5, 5, 3), np.uint8)).save(out / "train" / "rgb" / "00002.png")
    lab = np.full((14, 18), 37, np.uint8)
    Image.fromarray(lab).save(out / "train" / "label37" / "00003.png")
    (out / "test" / "rgb" / "00001.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    seq = SUNRGBDSequence(path=out)
    messages = []
    for i in range(4):
        with pytest.raises((DataFormatError, InvalidDataError)) as err:
            seq.frame(i)
        messages.append(str(err.value))
    assert messages[0].startswith(f"{out / 'train' / 'depth' / '00001.png'}: expected a 16-bit")
    assert messages[1] == (f"{out / 'train' / 'rgb' / '00002.png'}: image (per frames.txt) is "
                           "5x5, expected 20x10")
    assert messages[2].startswith(f"{out / 'train' / 'label37' / '00003.png'}: label 37 outside "
                                  "0..36 (255 void)")
    assert messages[3].startswith(f"{out / 'test' / 'rgb' / '00001.png'}: unreadable or corrupt")
    seq.frame(4)

    (out / "test" / "frames.txt").write_text("00001 1 2 3\n")
    with pytest.raises(DataFormatError, match=r"test/frames\.txt:1: expected 'id fx fy"):
        SUNRGBDSequence(path=out, split="test")
    shutil.rmtree(out / "train" / "label37")
    with pytest.raises(DataFormatError, match="label37 folder not found"):
        SUNRGBDSequence(path=out, split="train")
    with pytest.raises(EvsmapError, match="unknown sunrgbd split 'val'"):
        SUNRGBDSequence(path=out, split="val")
