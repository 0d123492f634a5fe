import json
import shutil

import numpy as np
import pytest
import scipy.io
from datasets_fixtures import NYU_TEST, NYU_TRAIN, nyu_map_class, write_nyu_source
from PIL import Image

from evsmap.classes import NYU40_CLASSES
from evsmap.datasets.common import MANIFEST
from evsmap.datasets.nyuv2 import (
    DEPTH_SCALE,
    NYUV2_INTRINSICS,
    NYUv2Sequence,
    is_nyuv2_folder,
    prepare_nyuv2,
)
from evsmap.errors import DataFormatError, EvsmapError, InvalidDataError
from evsmap.registry import READERS


@pytest.fixture(scope="module")
def samples(nyuv2_samples_dir):
    return nyuv2_samples_dir


def test_real_samples(samples):
    seq = READERS.create("nyuv2", path=str(samples))
    assert len(seq) == 2 and seq.names == ["000433", "000464"]
    assert seq.intrinsics == NYUV2_INTRINSICS
    assert seq.meta["poses"] is False and seq.meta["layout"] == "nyuv2"
    assert seq.meta["num_classes"] == 40 and seq.meta["class_names"] == list(NYU40_CLASSES)
    assert len(seq.meta["class_colors"]) == 40 and seq.class_names == NYU40_CLASSES
    for i, frame in enumerate(seq):
        assert frame.rgb.shape == (480, 640, 3) and frame.depth.shape == (480, 640)
        assert np.array_equal(frame.pose, np.eye(4)) and frame.timestamp == i
        valid = frame.depth[frame.depth > 0]
        assert valid.size > 0.5 * frame.depth.size
        assert 0.5 < valid.min() and valid.max() < 10.0
        png = np.asarray(Image.open(samples / "label40" / f"{frame.name}.png"))
        assert np.array_equal(frame.labels, png)
        assert set(np.unique(frame.labels)) == set(np.unique(png))
        raw = np.asarray(Image.open(samples / "depth" / f"{frame.name}.png"))
        assert np.allclose(frame.depth, raw / 5000.0, atol=1e-6)
    assert {0, 1, 39, 255} <= set(np.unique(seq[0].labels))  # wall, floor, otherprop, void
    assert len(READERS.create("nyuv2", path=str(samples), limit=1)) == 1


def test_samples_have_no_split_files(samples):
    with pytest.raises(DataFormatError, match=r"train\.txt: split file not found"):
        NYUv2Sequence(path=samples, split="train")
    with pytest.raises(EvsmapError, match="unknown nyuv2 split 'val'"):
        NYUv2Sequence(path=samples, split="val")
    with pytest.raises(EvsmapError, match="limit must be a positive integer"):
        NYUv2Sequence(path=samples, limit=0)


def test_prepare_round_trip(nyu_source, nyu_prepared_session):
    src, arrays = nyu_source
    out = nyu_prepared_session
    assert is_nyuv2_folder(out)
    manifest = json.loads((out / MANIFEST).read_text())
    assert manifest["name"] == "nyuv2" and manifest["splits"] == {"train": 3, "test": 2}
    assert manifest["source"] == str(src.resolve()) and manifest["version"] == 1
    assert manifest["depth_beyond_range_pixels"] == 5  # the 20 m corner of each frame
    assert (out / "train.txt").read_text().split() == [f"{i:06d}" for i in NYU_TRAIN]
    assert (out / "test.txt").read_text().split() == [f"{i:06d}" for i in NYU_TEST]
    lut = np.concatenate([[255], nyu_map_class().astype(int) - 1])
    seq = NYUv2Sequence(path=out)
    assert seq.names == [f"{i:06d}" for i in range(1, 6)]
    for frame in seq:
        k = int(frame.name) - 1
        # orientation: the bright block is top-left, x runs along columns
        assert np.array_equal(frame.rgb, arrays["rgb"][k])
        assert frame.rgb[0, 0].tolist() == [255, 255, 255] and frame.rgb[0, 25, 0] == 25
        d = arrays["depth"][k].astype(np.float64)
        expect = np.round(d * DEPTH_SCALE) / DEPTH_SCALE
        expect[d > 13.1] = 0.0
        assert np.allclose(frame.depth, expect, atol=1e-6)
        assert np.all(frame.depth[:, :8] == 0)
        assert np.array_equal(frame.labels, lut[arrays["labels"][k]])
        assert np.all(frame.labels[arrays["labels"][k] == 0] == 255)  # source void stays void
    train = NYUv2Sequence(path=out, split="train")
    test = NYUv2Sequence(path=out, split="test", limit=1)
    assert train.names == ["000001", "000003", "000004"] and test.names == ["000002"]


def test_prepare_limit_and_overwrite(nyu_source, tmp_path):
    src = nyu_source[0]
    out = tmp_path / "out"
    seen = []
    manifest = prepare_nyuv2(src, out, limit=1, progress=lambda items: seen.extend(items) or items)
    assert manifest["splits"] == {"train": 1, "test": 1} and manifest["limit"] == 1
    assert seen == [("train", 1), ("test", 2)]
    assert sorted(p.name for p in (out / "rgb").iterdir()) == ["000001.png", "000002.png"]
    with pytest.raises(EvsmapError, match="not empty"):
        prepare_nyuv2(src, out)
    prepare_nyuv2(src, out, limit=2, overwrite=True)
    assert len(NYUv2Sequence(path=out)) == 4
    assert not list(tmp_path.glob(".out.*"))  # no partial or old folder left behind
    with pytest.raises(EvsmapError, match="would replace the source"):
        prepare_nyuv2(src, src, overwrite=True)


@pytest.mark.parametrize("missing", ["nyu_depth_v2_labeled.mat", "splits.mat",
                                     "classMapping40.mat"])
def test_prepare_missing_source_file(nyu_source, tmp_path, missing):
    src = tmp_path / "src"
    src.mkdir()
    for f in nyu_source[0].iterdir():
        if f.name != missing:
            (src / f.name).symlink_to(f)
    with pytest.raises(DataFormatError) as err:
        prepare_nyuv2(src, tmp_path / "out")
    assert str(err.value).startswith(f"{src / missing}: ") and "not found" in str(err.value)
    assert not (tmp_path / "out").exists()


def test_prepare_rejects_bad_sources(tmp_path):
    arrays = {"rgb": np.zeros((2, 480, 640, 3), np.uint8),
              "depth": np.ones((2, 480, 640), np.float32),
              "labels": np.zeros((2, 480, 640), np.uint16)}
    wrong = tmp_path / "wrong"
    write_nyu_source(wrong, arrays, transposed_wrong=True)
    with pytest.raises(DataFormatError, match=r"nyu_depth_v2_labeled\.mat: dataset 'images' "
                                              r"has shape \(2, 3, 480, 640\), expected N x 3 x "
                                              r"640 x 480"):
        prepare_nyuv2(wrong, tmp_path / "o1")

    arrays["labels"][1, 5, 5] = 900
    bad_label = tmp_path / "bad_label"
    write_nyu_source(bad_label, arrays)
    scipy.io.savemat(bad_label / "splits.mat", {"trainNdxs": np.array([[1.0]]),
                                                "testNdxs": np.array([[2.0]])})
    with pytest.raises(DataFormatError, match="labels of frame 2 hold value 900 outside 0..894"):
        prepare_nyuv2(bad_label, tmp_path / "o2")

    scipy.io.savemat(bad_label / "splits.mat", {"trainNdxs": np.array([[1.0], [7.0]]),
                                                "testNdxs": np.array([[2.0]])})
    with pytest.raises(DataFormatError, match=r"splits\.mat: trainNdxs has index 7 outside 1..2"):
        prepare_nyuv2(bad_label, tmp_path / "o3")

    scipy.io.savemat(bad_label / "classMapping40.mat", {"mapClass": np.full((1, 894), 41.0)})
    with pytest.raises(DataFormatError, match=r"classMapping40\.mat: mapClass values must be "
                                              r"integers in 1..40"):
        prepare_nyuv2(bad_label, tmp_path / "o4")
    (bad_label / "nyu_depth_v2_labeled.mat").write_bytes(b"MATLAB 5.0 MAT-file" + b"\0" * 200)
    scipy.io.savemat(bad_label / "classMapping40.mat", {"mapClass": nyu_map_class()[None]})
    with pytest.raises(DataFormatError, match=r"labeled\.mat: not a MATLAB v7\.3 \(HDF5\) file"):
        prepare_nyuv2(bad_label, tmp_path / "o5")
    assert not any(tmp_path.glob("o*"))


def _error(seq, index):
    with pytest.raises((DataFormatError, InvalidDataError)) as err:
        seq.frame(index)
    return str(err.value)


def test_bad_frames_raise_from_frame(nyu_prepared):
    out = nyu_prepared
    rgb1 = out / "rgb" / "000001.png"
    rgb1.write_bytes(rgb1.read_bytes()[:500])  # truncated
    Image.fromarray(np.zeros((480, 640), np.uint8)).save(out / "depth" / "000002.png")
    Image.fromarray(np.zeros((240, 320, 3), np.uint8)).save(out / "rgb" / "000003.png")
    lab = np.asarray(Image.open(out / "label40" / "000004.png")).copy()
    lab[0, 0] = 57
    Image.fromarray(lab).save(out / "label40" / "000004.png")
    (out / "label40" / "000005.png").unlink()
    seq = NYUv2Sequence(path=out)  # opening still works; each bad frame fails on its own
    assert len(seq) == 5
    assert _error(seq, 0).startswith(f"{rgb1}: unreadable or corrupt image")
    msg = _error(seq, 1)
    assert msg.startswith(f"{out / 'depth' / '000002.png'}: ") and "16-bit" in msg
    assert "got mode L" in msg
    assert _error(seq, 2) == f"{out / 'rgb' / '000003.png'}: image is 320x240, expected 640x480"
    assert _error(seq, 3).startswith(
        f"{out / 'label40' / '000004.png'}: label 57 outside 0..39 (255 void)")
    assert _error(seq, 4) == f"{out / 'label40' / '000005.png'}: file not found"
    for msg in (_error(seq, i) for i in range(5)):
        assert "\n" not in msg


def test_missing_folders_raise_at_open(nyu_prepared, tmp_path):
    (nyu_prepared / "test.txt").unlink()
    assert len(NYUv2Sequence(path=nyu_prepared, split="train")) == 3
    with pytest.raises(DataFormatError, match=r"test\.txt: split file not found"):
        NYUv2Sequence(path=nyu_prepared, split="test")
    shutil.rmtree(nyu_prepared / "label40")
    with pytest.raises(DataFormatError, match=r"label40: NYUv2 label40 folder not found"):
        NYUv2Sequence(path=nyu_prepared)
    with pytest.raises(DataFormatError, match="not a folder"):
        NYUv2Sequence(path=tmp_path / "nope")


@pytest.mark.parametrize("text", ["", "# nothing\n", "../rgb/000001\n", "000001/x\n",
                                  "0000\x0001\n"])
def test_split_file_that_lists_no_usable_frame(nyu_prepared, text):
    (nyu_prepared / "test.txt").write_text(text)
    with pytest.raises(DataFormatError, match=f"^{nyu_prepared / 'test.txt'}"):
        NYUv2Sequence(path=nyu_prepared, split="test")


def test_labelled_file_with_fractional_labels(tmp_path):
    arrays = {"rgb": np.zeros((2, 480, 640, 3), np.uint8),
              "depth": np.ones((2, 480, 640), np.float32),
              "labels": np.full((2, 480, 640), 2.5, np.float32)}
    write_nyu_source(tmp_path / "src", arrays)
    scipy.io.savemat(tmp_path / "src" / "splits.mat", {"trainNdxs": np.array([[1.0]]),
                                                       "testNdxs": np.array([[2.0]])})
    with pytest.raises(DataFormatError, match="labels of frame 1 hold non-integer values"):
        prepare_nyuv2(tmp_path / "src", tmp_path / "out")
