"""Training samples: the inference preprocessing at scale 1, padding with void, crop, flip,
determinism by (seed, epoch, frame), the epoch keys of the sampler, opening splits."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.utils.data import DistributedSampler
from train_fixtures import SIZE, colour_frames

from evsmap.data import VOID
from evsmap.errors import EvsmapError, InvalidDataError
from evsmap.registry import SEGMENTERS
from evsmap.train.data import EpochKeys, TrainingFrames, open_splits, scaled_size


@pytest.fixture(scope="module")
def segmenter():
    return SEGMENTERS.create("feagnet-v1", num_classes=4, input_size=SIZE)


def _frames(segmenter, sequence, **kw):
    kw.setdefault("crop", SIZE)
    return TrainingFrames(sequence, normalization=segmenter.normalization, uses_depth=True,
                          input_size=SIZE, num_classes=4, **kw)


def test_scale_one_is_the_inference_preprocessing(segmenter):
    seq = colour_frames(2, height=60, width=80)  # resized to the input size like at inference
    ds = _frames(segmenter, seq)
    for i in range(2):
        item = ds[(3, i)]
        rgb, depth = segmenter.preprocess(seq.frame(i))
        assert torch.equal(item["rgb"], rgb[0]) and torch.equal(item["depth"], depth[0])
        expected = torch.nn.functional.interpolate(
            torch.from_numpy(seq.frame(i).labels.astype(np.float32))[None, None], size=SIZE,
            mode="nearest")[0, 0].long()
        assert torch.equal(item["labels"], expected)
        assert item["labels"].dtype == torch.int64 and int(item["index"]) == i


def test_padding_is_void_and_zero(segmenter):
    seq = colour_frames(1)
    ds = _frames(segmenter, seq, scale=(0.5, 0.5))
    item = ds[(0, 0)]
    h, w = scaled_size(SIZE, 0.5)
    assert item["rgb"].shape == (3, *SIZE) and item["labels"].shape == SIZE
    pad = torch.ones(SIZE, dtype=torch.bool)
    pad[:h, :w] = False  # the image sits at the top left, the crop covers it all
    assert bool((item["labels"][pad] == VOID).all())
    assert bool((item["rgb"][:, pad] == 0).all()) and bool((item["depth"][:, pad] == 0).all())
    assert bool((item["labels"][~pad] != VOID).any())


def test_crop_and_flip(segmenter):
    seq = colour_frames(1)
    big = _frames(segmenter, seq, scale=(2.0, 2.0), crop=(64, 96))
    item = big[(0, 0)]
    assert item["rgb"].shape == (3, 64, 96) and item["depth"].shape == (1, 64, 96)
    # the crop is a window of the image at scale 2
    full = _frames(segmenter, seq, scale=(2.0, 2.0), crop=scaled_size(SIZE, 2.0))[(0, 0)]
    d = big.draws(0, 0)
    y0 = int(d["y"] * (full["rgb"].shape[1] - 64 + 1))
    x0 = int(d["x"] * (full["rgb"].shape[2] - 96 + 1))
    window = full["labels"][y0:y0 + 64, x0:x0 + 96]
    assert torch.equal(item["labels"], window.flip(-1) if d["flip"] else window)
    flipped = _frames(segmenter, seq, flip=1.0)[(0, 0)]
    plain = _frames(segmenter, seq, flip=0.0)[(0, 0)]
    for key in ("rgb", "depth", "labels"):
        assert torch.equal(flipped[key], plain[key].flip(-1))


def test_samples_depend_on_seed_epoch_and_frame_only(segmenter):
    seq = colour_frames(2)
    ds = _frames(segmenter, seq, scale=(0.5, 2.0), crop=(64, 96), flip=0.5, seed=3)
    a = ds[(5, 1)]
    ds[(0, 0)]  # anything in between
    b = _frames(segmenter, seq, scale=(0.5, 2.0), crop=(64, 96), flip=0.5, seed=3)[(5, 1)]
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert len({tuple(ds.draws(e, 1).values()) for e in range(4)}) == 4  # anew every epoch
    other = TrainingFrames(seq, normalization=segmenter.normalization, uses_depth=True,
                           input_size=SIZE, crop=(64, 96), scale=(0.5, 2.0), flip=0.5, seed=4,
                           num_classes=4)
    assert other.draws(5, 1) != ds.draws(5, 1)


def test_labels_outside_the_classes(segmenter):
    seq = colour_frames(1)
    ds = TrainingFrames(seq, normalization=segmenter.normalization, uses_depth=True,
                        input_size=SIZE, crop=SIZE, num_classes=3)
    with pytest.raises(InvalidDataError, match="label 3, outside 0..2.*num_classes"):
        ds[0]


def test_rgb_only_networks_get_no_depth():
    seg = SEGMENTERS.create("feagnet-s", num_classes=4, input_size=SIZE)
    ds = TrainingFrames(colour_frames(1), normalization=seg.normalization, uses_depth=False,
                        input_size=SIZE, crop=SIZE, num_classes=4)
    assert set(ds[0]) == {"rgb", "labels", "index"}


def test_epoch_keys_split_the_shuffled_frames():
    keys = [EpochKeys(DistributedSampler(range(10), num_replicas=2, rank=r, shuffle=True,
                                         seed=0, drop_last=True)) for r in (0, 1)]
    for k in keys:
        k.set_epoch(3)
    got = [list(k) for k in keys]
    assert all(e == 3 for part in got for e, _ in part)
    indices = [i for part in got for _, i in part]
    assert sorted(indices) == list(range(10)) and len(keys[0]) == 5
    one = EpochKeys(DistributedSampler(range(10), num_replicas=1, rank=0, shuffle=True, seed=0))
    one.set_epoch(3)
    order = [i for _, i in one]
    assert order[0::2] == [i for _, i in got[0]] and order[1::2] == [i for _, i in got[1]]
    one.set_epoch(4)
    assert [i for _, i in one] != order


def test_open_splits_without_splits(colour_data):
    splits = open_splits(str(colour_data))
    assert splits.reader == "tum" and splits.train_split is None and splits.val is splits.train
    assert len(splits.train) == 8 and splits.num_classes is None
    assert len(open_splits(str(colour_data), limit=3).train) == 3
    with pytest.raises(EvsmapError, match="has no splits"):
        open_splits(str(colour_data), val_split="test")
    with pytest.raises(EvsmapError, match="--train-split"):
        open_splits(str(colour_data), reader_options=[("split", "train")])


def test_open_splits_with_splits(tmp_path):
    from evsmap.data import FrameList
    from evsmap.registry import READERS

    calls = []

    def factory(*, path: str, split: str = "all", limit: int | None = None) -> FrameList:
        calls.append((split, limit))
        seq = colour_frames(3 if split == "train" else 2)
        seq.meta.update(num_classes=4, class_names=["a", "b", "c", "d"])
        return seq

    READERS.add("traintest-split", factory)
    try:
        splits = open_splits(str(tmp_path), reader="traintest-split", limit=5)
        assert calls == [("train", 5), ("test", 5)]
        assert (splits.train_split, splits.val_split) == ("train", "test")
        assert (len(splits.train), len(splits.val), splits.num_classes) == (3, 2, 4)
        assert splits.class_names == ("a", "b", "c", "d")
        open_splits(str(tmp_path), reader="traintest-split", train_split="all",
                    val_split="train")
        assert calls[-2:] == [("all", None), ("train", None)]
    finally:
        READERS.unregister("traintest-split")
