import json
import shutil

import numpy as np
import pytest
from datasets_fixtures import CITY_FRAMES, write_city_tree
from PIL import Image

from evsmap.classes import CITYSCAPES19_CLASSES
from evsmap.data import Intrinsics
from evsmap.datasets.cityscapes import (
    CityscapesSequence,
    disparity_to_depth,
    is_cityscapes_folder,
    prepare_cityscapes,
)
from evsmap.datasets.cityscapes_labels import (
    CITYSCAPES19_COLORS,
    CITYSCAPES19_NAMES,
    CITYSCAPES_LABELS,
    LABEL_ID_TO_TRAIN_ID,
    label_ids_to_train_ids,
)
from evsmap.datasets.common import MANIFEST
from evsmap.errors import DataFormatError, EvsmapError, InvalidDataError
from evsmap.registry import READERS


def test_label_table():
    assert CITYSCAPES19_NAMES == CITYSCAPES19_CLASSES
    assert [lab.id for lab in CITYSCAPES_LABELS] == [*range(34), -1]
    train = {lab.id: lab.train_id for lab in CITYSCAPES_LABELS if lab.train_id not in (255, -1)}
    assert train == {7: 0, 8: 1, 11: 2, 12: 3, 13: 4, 17: 5, 19: 6, 20: 7, 21: 8, 22: 9, 23: 10,
                     24: 11, 25: 12, 26: 13, 27: 14, 28: 15, 31: 16, 32: 17, 33: 18}
    assert LABEL_ID_TO_TRAIN_ID[-1] == 255 and LABEL_ID_TO_TRAIN_ID[0] == 255
    assert sum(v != 255 for v in LABEL_ID_TO_TRAIN_ID.values()) == 19
    assert CITYSCAPES19_COLORS.shape == (19, 3) and CITYSCAPES19_COLORS.dtype == np.uint8
    assert CITYSCAPES19_COLORS[0].tolist() == [128, 64, 128]  # road
    assert CITYSCAPES19_COLORS[18].tolist() == [119, 11, 32]  # bicycle
    ids = np.arange(34, dtype=np.uint8)[None]
    assert label_ids_to_train_ids(ids)[0].tolist() == [LABEL_ID_TO_TRAIN_ID[i] for i in range(34)]
    with pytest.raises(InvalidDataError, match="x.png: label id 34 outside 0..33 at 1 pixels"):
        label_ids_to_train_ids(np.array([[1, 34]], np.uint8), "x.png")


def test_disparity_to_depth():
    raw = np.array([[0, 1, 257, 2561]], dtype=np.uint16)
    depth = disparity_to_depth(raw, 0.2, 2000.0)
    assert depth.dtype == np.float32
    assert depth[0].tolist() == pytest.approx([0.0, 0.0, 400.0, 40.0])


def _expected(truth, resolution):
    cam = truth["camera"]
    fx = cam["intrinsic"]["fx"]
    baseline = cam["extrinsic"]["baseline"]
    depth = disparity_to_depth(truth["disp"], baseline, fx)
    labels = label_ids_to_train_ids(truth["ids"])
    rgb = truth["rgb"]
    intr = Intrinsics(fx, cam["intrinsic"]["fy"], cam["intrinsic"]["u0"], cam["intrinsic"]["v0"],
                      2048, 1024)
    if resolution == "1024x512":
        rgb = np.round(rgb.reshape(512, 2, 1024, 2, 3).astype(np.float64).mean(axis=(1, 3)))
        depth, labels = depth[::2, ::2], labels[::2, ::2]
        intr = intr.scaled(1024, 512)
    return rgb, depth, labels, intr


def test_official_tree_native(city_tree):
    root, truth = city_tree
    assert is_cityscapes_folder(root)
    seq = READERS.create("cityscapes", path=str(root), split="train", resolution="2048x1024")
    assert seq.names == [f"train/{stem}" for _, stem in CITY_FRAMES["train"]]
    assert seq.meta["poses"] is False and seq.meta["class_names"] == list(CITYSCAPES19_CLASSES)
    assert seq.meta["class_colors"][13] == [0, 0, 142]  # car
    frame = seq[1]
    rgb, depth, labels, intr = _expected(truth["train/bochum_000000_000313"], "2048x1024")
    assert np.array_equal(frame.rgb, rgb) and np.array_equal(frame.labels, labels)
    assert np.allclose(frame.depth, depth) and frame.intrinsics == intr
    assert frame.depth[:, :64].max() == 0 and frame.depth[:10, 64:128].max() == 0
    assert set(np.unique(frame.labels)) == {*range(19), 255}


@pytest.mark.parametrize("prepared", [False, True])
def test_half_resolution_from_tree_and_prepared(city_tree, city_prepared, prepared):
    root, truth = city_tree
    seq = CityscapesSequence(path=city_prepared if prepared else root)
    assert seq.meta["prepared"] is prepared and seq.meta["resolution"] == "1024x512"
    assert seq.names == ["train/aachen_000000_000019", "train/bochum_000000_000313",
                         "val/frankfurt_000000_000294", "test/berlin_000000_000019"]
    assert seq.intrinsics == _expected(truth["train/aachen_000000_000019"], "1024x512")[3]
    for i in (0, 2):
        frame = seq[i]
        rgb, depth, labels, intr = _expected(truth[frame.name], "1024x512")
        assert frame.rgb.shape == (512, 1024, 3) and frame.intrinsics == intr
        assert np.abs(frame.rgb.astype(int) - rgb).max() <= 1
        assert np.allclose(frame.depth, depth) and np.array_equal(frame.labels, labels)
    test = seq[3]
    assert test.labels.shape == (512, 1024) and np.all(test.labels == 255)  # test: all void
    assert test.depth.max() > 0
    val = CityscapesSequence(path=city_prepared if prepared else root, split="val", limit=1)
    assert val.names == ["val/frankfurt_000000_000294"]


def test_prepare_writes_train_ids(city_tree, city_prepared):
    root, truth = city_tree
    manifest = json.loads((city_prepared / MANIFEST).read_text())
    assert manifest["name"] == "cityscapes" and manifest["source"] == str(root.resolve())
    assert manifest["splits"] == {"train": 2, "val": 1, "test": 1}
    assert manifest["official_counts"] == {"train": 2975, "val": 500, "test": 1525}
    assert (city_prepared / "train.txt").read_text().split() == [
        "aachen/aachen_000000_000019", "bochum/bochum_000000_000313"]
    png = city_prepared / "gtFine" / "val" / "frankfurt" / \
        "frankfurt_000000_000294_gtFine_labelTrainIds.png"
    ids = truth["val/frankfurt_000000_000294"]["ids"]
    assert np.array_equal(np.asarray(Image.open(png)), label_ids_to_train_ids(ids))
    assert is_cityscapes_folder(city_prepared)


def test_test_split_without_labels(tmp_path):
    root = tmp_path / "cs"
    write_city_tree(root, {"test": [("bonn", "bonn_000000_000019")]}, test_labels=False)
    seq = CityscapesSequence(path=root, split="test", resolution="2048x1024")
    assert np.all(seq[0].labels == 255) and seq.meta["void_label_splits"] == ["test"]
    manifest = prepare_cityscapes(root, tmp_path / "out", limit=1)
    assert manifest["splits"] == {"test": 1}
    assert np.all(CityscapesSequence(path=tmp_path / "out")[0].labels == 255)


def test_bad_frames_raise_from_frame(small_city):
    root, _ = small_city
    rel = "val/lindau/lindau_000000_000019"
    ids = np.zeros((1024, 2048), np.uint8)
    ids[3, 3] = 40
    Image.fromarray(ids).save(root / "gtFine" / f"{rel}_gtFine_labelIds.png")
    seq = CityscapesSequence(path=root)
    with pytest.raises(InvalidDataError) as err:
        seq.frame(0)
    assert str(err.value) == (f"{root / 'gtFine' / f'{rel}_gtFine_labelIds.png'}: label id 40 "
                              "outside 0..33 at 1 pixels")
    with pytest.raises(InvalidDataError, match="label id 40"):
        prepare_cityscapes(root, root.parent / "out")

    Image.fromarray(np.zeros((1024, 2048), np.uint8)).save(
        root / "gtFine" / f"{rel}_gtFine_labelIds.png")
    camera = root / "camera" / f"{rel}_camera.json"
    camera.write_text('{"extrinsic": {}}')
    with pytest.raises(DataFormatError) as err:
        CityscapesSequence(path=root).frame(0)  # opening falls back, the frame fails
    assert str(err.value) == (f"{camera}: expected extrinsic.baseline and "
                              "intrinsic.fx/fy/u0/v0")
    with pytest.raises(DataFormatError, match="expected extrinsic.baseline"):
        prepare_cityscapes(root, root.parent / "out")

    camera.unlink()
    disparity = root / "disparity" / f"{rel}_disparity.png"
    Image.fromarray(np.zeros((1024, 2048), np.uint8)).save(disparity)
    seq = CityscapesSequence(path=root)
    with pytest.raises(DataFormatError, match=f"{disparity}: expected a 16-bit"):
        seq.frame(0)
    with pytest.raises(DataFormatError, match=f"{disparity}: expected a 16-bit disparity image, "
                                              "got mode L"):
        prepare_cityscapes(root, root.parent / "out")
    rgb = root / "leftImg8bit" / f"{rel}_leftImg8bit.png"
    Image.fromarray(np.zeros((512, 1024, 3), np.uint8)).save(rgb)
    with pytest.raises(DataFormatError) as err:
        seq.frame(0)
    assert str(err.value) == f"{rgb}: image is 1024x512, expected 2048x1024"
    assert not (root.parent / "out").exists()


def test_missing_folders_raise_at_open(small_city, tmp_path):
    root, _ = small_city
    with pytest.raises(DataFormatError, match=r"leftImg8bit/train: Cityscapes leftImg8bit/train "
                                              "folder not found"):
        CityscapesSequence(path=root, split="train")
    with pytest.raises(EvsmapError, match="unknown Cityscapes resolution '640x480'"):
        CityscapesSequence(path=root, resolution="640x480")
    shutil.rmtree(root / "camera")
    with pytest.raises(DataFormatError, match=r"camera/val: Cityscapes camera/val folder"):
        CityscapesSequence(path=root)
    with pytest.raises(DataFormatError, match=r"camera/val: Cityscapes camera/val "
                                              r"\(camera_trainvaltest.zip\) folder not found"):
        prepare_cityscapes(root, tmp_path / "out")
    shutil.rmtree(root / "gtFine")
    with pytest.raises(DataFormatError, match=r"gtFine/val: Cityscapes gtFine/val folder"):
        CityscapesSequence(path=root)


def test_prepared_folder_needs_its_source(city_prepared, tmp_path):
    moved = tmp_path / "prep"
    shutil.copytree(city_prepared, moved)
    manifest = json.loads((moved / MANIFEST).read_text())
    manifest["source"] = str(tmp_path / "gone")
    (moved / MANIFEST).write_text(json.dumps(manifest))
    with pytest.raises(DataFormatError, match="prepare it again"):
        CityscapesSequence(path=moved)
    for source in ("", ".", 5, "relative/tree"):  # not an absolute path to a tree
        manifest["source"] = source
        (moved / MANIFEST).write_text(json.dumps(manifest))
        with pytest.raises(DataFormatError, match=f"^{moved / MANIFEST}: .*prepare it again"):
            CityscapesSequence(path=moved)


@pytest.mark.parametrize("line", ["../../etc/x", "lindau", "lindau/", "a/b/c", "lindau/x\\y"])
def test_prepared_list_lines_that_cannot_name_a_frame(city_prepared, tmp_path, line):
    moved = tmp_path / "prep"
    shutil.copytree(city_prepared, moved)
    (moved / "val.txt").write_text(f"{line}\n")
    with pytest.raises(DataFormatError, match=f"^{moved / 'val.txt'}:1: id .* cannot name a "
                                              "frame's files"):
        CityscapesSequence(path=moved, split="val")


def test_prepared_list_naming_a_frame_without_image(city_prepared, tmp_path):
    moved = tmp_path / "prep"
    shutil.copytree(city_prepared, moved)
    (moved / "val.txt").write_text("frankfurt/frankfurt_000000_999999\n")
    with pytest.raises(DataFormatError, match=f"^{moved / 'val.txt'}: frame frankfurt/"
                                              "frankfurt_000000_999999 has no image "):
        CityscapesSequence(path=moved, split="val")


@pytest.mark.parametrize("resolution", ["2048x1024", "1024x512"])
def test_frames_carry_the_disparity_scale_esanet_reads_back(city_tree, resolution):
    """A frame's disparity scale is baseline x native fx at any resolution, and ESANet's
    Cityscapes encoding turns the frame's metres back into the disparity PNG's values."""
    from baselines.segmenters import _ESANET_DEPTH

    root, truth = city_tree
    seq = CityscapesSequence(path=root, split="train", resolution=resolution)
    frame = seq[1]
    cam = truth[frame.name]["camera"]
    assert frame.disparity_scale == pytest.approx(
        cam["extrinsic"]["baseline"] * cam["intrinsic"]["fx"], rel=1e-12)
    encoding = _ESANET_DEPTH["cityscapes"]
    assert encoding.depth_encoding == "cityscapes-disparity"
    png = encoding.encode_depth(frame.depth, frame)
    disp = truth[frame.name]["disp"].astype(np.float32)
    if resolution == "1024x512":
        disp = disp[::2, ::2]
    measured = disp > 1  # 0: no measurement, 1: zero disparity; both read as invalid depth
    assert np.array_equal(png[measured], disp[measured])
    assert np.all(png[~measured] == 0)
