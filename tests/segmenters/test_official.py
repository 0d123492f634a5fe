"""Official release checkpoints (ESANet, FC-HarDNet) through the normal ``weights=`` path.

Each test builds an official-layout file from the key tables of
:mod:`evsmap.segmenters.official`: the tensors are those of an evsmap network plus a seeded
random offset (so that default initial values - unit BatchNorm weights, the bilinear upsampling
kernels - cannot hide a wrong mapping), renamed to the official keys and saved in the release
wrappers (ESANet ``{'state_dict': ...}``; FC-HarDNet ``{'epoch', 'model_state', 'best_iou'}``
with DataParallel's ``module.`` prefix and a numpy float64). The file must load strictly and
give the outputs of the directly loaded evsmap-named tensors.

The official key sets themselves are pinned by fingerprints taken from the official code
(TUI-NICR/ESANet ``src/models/model.py`` ``ESANet(encoder_rgb='resnet34',
encoder_depth='resnet34', encoder_block='NonBottleneck1D', channels_decoder=[512, 256, 128],
nr_decoder_blocks=[3, 3, 3], upsampling='learned-3x3-zeropad', context_module=...)`` and
PingoLH/FCHarDNet ``ptsemseg/models/hardnet.py`` ``hardnet(n_classes=19)``, instantiated
without pretrained weights): SHA-256 of the sorted lines ``"<key> [<shape>]"`` of their
``state_dict()``.
"""

from __future__ import annotations

import hashlib
import io
import json
import subprocess
import sys
import zipfile
from collections import OrderedDict
from pathlib import Path

import numpy as np
import pytest
import torch

from evsmap.cli.main import main
from evsmap.errors import DataFormatError
from evsmap.segmenters import official
from evsmap.segmenters.official import (
    ESANET,
    EVSMAP,
    FCHARDNET,
    PLAIN,
    convert_state,
    esanet_table,
    fchardnet_table,
)
from evsmap.segmenters.weights import read_checkpoint, read_weights, tensors_sha256

ESANET_NAME = "esanet-r34-nbt1d"
HARDNET_NAME = "fchardnet-70"

# configuration -> (tensors in the release, fingerprint of the official key set)
ESANET_OFFICIAL = {
    "nyuv2": (898, "3d9ebe2b000f641462c8da1a156883a60c6bbd0d3c13ae603bfae8578ca84f10"),
    "sunrgbd": (898, "279ef616e608600a16e3ee839d2fd1a2aba2a3a7d4f02d8477910c15dcd93941"),
    "cityscapes": (910, "ddd3182e8aea9eaa298cf48ec4fe78080b4ae1f1aa582d0ccc81b41922184e92"),
}
HARDNET_OFFICIAL = (416, "67362b2aed6dbf4d0f2f36d30591fab55179efffd3dfe456d2a05e83eb1bd97e")

# FC-HarDNet's official input: BGR, ImageNet statistics in BGR order (cityscapes_loader.py)
BGR_MEAN = (0.406, 0.456, 0.485)
BGR_STD = (0.225, 0.224, 0.229)


# ------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------


def _fingerprint(state: dict[str, torch.Tensor]) -> str:
    lines = "\n".join(f"{k} {list(v.shape)}" for k, v in sorted(state.items()))
    return hashlib.sha256(lines.encode()).hexdigest()


def _perturbed(module: torch.nn.Module, seed: int) -> dict[str, torch.Tensor]:
    """The module's tensors plus a seeded offset (running variances kept positive)."""
    gen = torch.Generator().manual_seed(seed)
    out = {}
    for key, value in module.state_dict().items():
        if value.is_floating_point():
            offset = torch.randn(value.shape, generator=gen) * 0.05
            out[key] = value + 0.5 + offset.abs() if key.endswith("running_var") \
                else value + offset
        else:
            out[key] = torch.randint(1, 1000, value.shape, generator=gen, dtype=value.dtype)
    return out


def _to_official(state: dict[str, torch.Tensor], table: dict[str, str]) -> dict[str, torch.Tensor]:
    """evsmap-named tensors under the official names (the key table read backwards)."""
    back = {ours: theirs for theirs, ours in table.items()}
    out = {}
    for key, value in state.items():
        module, _, leaf = key.rpartition(".")
        out[f"{back[module]}.{leaf}"] = value.clone()
    return out


def _esanet_context(dataset: str) -> str:
    return official.ESANET_RELEASES[dataset][0]


def _logits(seg, *inputs) -> torch.Tensor:
    with torch.inference_mode():
        return seg.module(*inputs)


def _error(fn) -> str:
    with pytest.raises(DataFormatError) as info:
        fn()
    message = str(info.value)
    assert "\n" not in message
    return message


# ------------------------------------------------------------------------------------------
# the key tables
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("dataset", sorted(ESANET_OFFICIAL))
def test_esanet_table_gives_the_official_key_set(create, dataset):
    module = create(ESANET_NAME, dataset=dataset).module
    own = module.state_dict()
    table = esanet_table(_esanet_context(dataset))
    assert set(table.values()) == {k.rpartition(".")[0] for k in own}  # every module, once
    theirs = _to_official(own, table)
    count, fingerprint = ESANET_OFFICIAL[dataset]
    assert len(theirs) == len(own) == count
    assert _fingerprint(theirs) == fingerprint


def test_fchardnet_table_gives_the_official_key_set(create):
    own = create(HARDNET_NAME, dataset="cityscapes").module.state_dict()
    table = fchardnet_table()
    assert set(table.values()) == {k.rpartition(".")[0] for k in own}
    theirs = _to_official(own, table)
    assert (len(theirs), _fingerprint(theirs)) == HARDNET_OFFICIAL


ESANET_PAIRS = [  # (context, official key, evsmap key), read off the official modules
    ("ppm", "encoder_rgb.conv1.weight", "encoder_rgb.stem.0.weight"),
    ("ppm", "encoder_depth.bn1.running_var", "encoder_depth.stem.1.running_var"),
    ("ppm", "encoder_rgb.layer1.0.conv3x1_1.weight", "encoder_rgb.stages.0.0.conv_v1.weight"),
    ("ppm", "encoder_rgb.layer2.0.downsample.1.running_var",
     "encoder_rgb.stages.1.0.shortcut.1.running_var"),
    ("ppm", "encoder_depth.layer3.5.conv1x3_2.bias", "encoder_depth.stages.2.5.conv_h2.bias"),
    ("ppm", "encoder_depth.layer4.2.bn2.num_batches_tracked",
     "encoder_depth.stages.3.2.bn2.num_batches_tracked"),
    ("ppm", "se_layer0.se_rgb.fc.0.weight", "fusions.0.se_rgb.squeeze.weight"),
    ("ppm", "se_layer3.se_depth.fc.2.bias", "fusions.3.se_depth.excite.bias"),
    ("ppm", "skip_layer1.0.conv.weight", "skips.0.0.weight"),
    ("ppm", "skip_layer3.0.bn.running_mean", "skips.2.1.running_mean"),
    ("ppm", "context_module.features.1.1.conv.weight", "context.branches.1.0.weight"),
    ("ppm", "context_module.final_conv.bn.bias", "context.fuse.1.bias"),
    ("appm-1-2-4-8", "context_module.features.3.conv.weight", "context.branches.3.0.weight"),
    ("appm-1-2-4-8", "context_module.features.0.bn.weight", "context.branches.0.1.weight"),
    ("ppm", "decoder.decoder_module_1.conv3x3.conv.weight", "decoder.0.conv.0.weight"),
    ("ppm", "decoder.decoder_module_2.decoder_blocks.1.conv3x1_1.weight",
     "decoder.1.blocks.1.conv_v1.weight"),
    ("ppm", "decoder.decoder_module_3.upsample.conv.bias", "decoder.2.upsample.conv.bias"),
    ("ppm", "decoder.decoder_module_3.side_output.weight", "decoder.2.side_output.weight"),
    ("ppm", "decoder.conv_out.weight", "classifier.weight"),
    ("ppm", "decoder.upsample2.conv.weight", "upsample.1.conv.weight"),
]

HARDNET_PAIRS = [
    ("base.0.conv.weight", "encoder.stem.0.0.weight"),
    ("base.3.norm.weight", "encoder.stem.3.1.weight"),
    ("base.4.layers.3.conv.weight", "encoder.blocks.0.layers.3.0.weight"),
    ("base.5.norm.running_var", "encoder.transitions.0.1.running_var"),
    ("base.10.layers.7.conv.weight", "encoder.blocks.2.layers.7.0.weight"),
    ("base.14.conv.weight", "encoder.transitions.3.0.weight"),
    ("base.16.layers.7.norm.running_mean", "encoder.blocks.4.layers.7.1.running_mean"),
    ("base.17.norm.num_batches_tracked", "encoder.transitions.4.1.num_batches_tracked"),
    ("conv1x1_up.0.norm.bias", "reduce.0.1.bias"),
    ("denseBlocksUp.0.layers.7.conv.weight", "up_blocks.0.layers.7.0.weight"),
    ("denseBlocksUp.3.layers.3.norm.weight", "up_blocks.3.layers.3.1.weight"),
    ("finalConv.bias", "head.bias"),
]


@pytest.mark.parametrize(("context", "theirs", "ours"), ESANET_PAIRS,
                         ids=[p[1] for p in ESANET_PAIRS])
def test_esanet_key_pairs(context, theirs, ours):
    module, _, leaf = theirs.rpartition(".")
    assert f"{esanet_table(context)[module]}.{leaf}" == ours


@pytest.mark.parametrize(("theirs", "ours"), HARDNET_PAIRS, ids=[p[0] for p in HARDNET_PAIRS])
def test_fchardnet_key_pairs(theirs, ours):
    module, _, leaf = theirs.rpartition(".")
    assert f"{fchardnet_table()[module]}.{leaf}" == ours


def test_release_configurations_match_the_baseline():
    from baselines.esanet import DATASET_CONFIGS, STAGE_BLOCKS

    assert official.ESANET_STAGE_BLOCKS == STAGE_BLOCKS
    for dataset, (context, classes) in official.ESANET_RELEASES.items():
        assert DATASET_CONFIGS[dataset][0] == context
        assert DATASET_CONFIGS[dataset][2] == classes


# ------------------------------------------------------------------------------------------
# ESANet release files
# ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def esanet_release(create, tmp_path_factory):
    """dataset -> (release file, evsmap-named tensors it holds)."""
    cache: dict[str, tuple[Path, dict[str, torch.Tensor]]] = {}

    def get(dataset: str):
        if dataset not in cache:
            module = create(ESANET_NAME, dataset=dataset, seed=5).module
            state = _perturbed(module, seed=11)
            theirs = _to_official(state, esanet_table(_esanet_context(dataset)))
            path = tmp_path_factory.mktemp("esanet") / f"{dataset}_r34_NBt1D.pth"
            torch.save({"state_dict": theirs}, path)
            cache[dataset] = (path, state)
        return cache[dataset]

    return get


@pytest.mark.parametrize("dataset", sorted(ESANET_OFFICIAL))
def test_esanet_release_loads_strictly(create, esanet_release, dataset):
    path, state = esanet_release(dataset)
    loaded = create(ESANET_NAME, dataset=dataset, seed=2, weights=path)
    direct = create(ESANET_NAME, dataset=dataset, seed=3)
    direct.module.load_state_dict(state, strict=True)
    fresh = create(ESANET_NAME, dataset=dataset, seed=3)
    rgb, depth = loaded.example_inputs(*loaded.input_size)
    out = _logits(loaded, rgb, depth)
    assert torch.equal(out, _logits(direct, rgb, depth))
    assert not torch.equal(out, _logits(fresh, rgb, depth))
    converted = read_weights(path)
    assert converted.layout == ESANET and converted.dataset == dataset
    assert converted.num_classes == official.ESANET_RELEASES[dataset][1]
    assert len(converted.state) == ESANET_OFFICIAL[dataset][0]
    assert converted.options == {"dataset": dataset}


def test_esanet_configuration_mismatch_names_the_option(create, esanet_release):
    path, _ = esanet_release("cityscapes")
    message = _error(lambda: create(ESANET_NAME, weights=path))  # nyuv2: 40 classes, ppm
    assert str(path) in message
    assert "official ESANet release" in message and "cityscapes configuration" in message
    assert "19 classes, context appm-1-2-4-8" in message
    assert "40 classes, context ppm" in message
    assert "-o dataset=cityscapes" in message


def test_esanet_release_into_another_network(create, esanet_release):
    path, _ = esanet_release("nyuv2")
    message = _error(lambda: create(HARDNET_NAME, weights=path))
    assert "for esanet-r34-nbt1d (ESANet), not FCHarDNet" in message


def test_unmapped_official_keys_are_named(create, tmp_path):
    state = _perturbed(create(ESANET_NAME).module, seed=1)
    theirs = _to_official(state, esanet_table("ppm"))
    theirs["encoder_rgb.layer1.0.conv1.weight"] = torch.zeros(64, 64, 3, 3)  # a BasicBlock key
    path = tmp_path / "r34_basic.pth"
    torch.save({"state_dict": theirs}, path)
    message = _error(lambda: create(ESANET_NAME, weights=path))
    assert "official ESANet release" in message
    assert "1 of 899 keys have no evsmap name" in message
    assert "encoder_rgb.layer1.0.conv1.weight" in message


def test_unsupported_esanet_context_is_named():
    state = {k + ".weight": torch.zeros(1) for k in esanet_table("ppm")}
    state["decoder.conv_out.weight"] = torch.zeros(40, 128, 3, 3)
    state = {k: v for k, v in state.items() if not k.startswith("context_module.features.1")}
    message = _error(lambda: convert_state(state, source="x.pth"))
    assert "unsupported context module (1 pyramid branches" in message


# ------------------------------------------------------------------------------------------
# FC-HarDNet release file
# ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def hardnet_release(create, tmp_path_factory):
    """(release file, evsmap-named tensors in the official meaning: BGR first conv)."""
    module = create(HARDNET_NAME, dataset="cityscapes", seed=5).module
    state = _perturbed(module, seed=12)
    theirs = _to_official(state, fchardnet_table())
    path = tmp_path_factory.mktemp("hardnet") / "hardnet70_cityscapes_model.pkl"
    torch.save({"epoch": 10, "model_state": {f"module.{k}": v for k, v in theirs.items()},
                "best_iou": np.float64(0.7)}, path)
    return path, state


def _bgr_pipeline(rgb: np.ndarray) -> torch.Tensor:
    """The official preprocessing by hand: BGR, float64, ImageNet statistics in BGR order."""
    img = rgb[:, :, ::-1].astype(np.float64)
    img = (img - np.array(BGR_MEAN) * 255) / (np.array(BGR_STD) * 255)
    return torch.from_numpy(img.transpose(2, 0, 1).copy()).float()[None]


def test_fchardnet_release_loads_strictly(create, hardnet_release):
    path, state = hardnet_release
    loaded = create(HARDNET_NAME, dataset="cityscapes", seed=2, weights=path)
    flipped = dict(state)
    flipped["encoder.stem.0.0.weight"] = state["encoder.stem.0.0.weight"].flip(1)
    direct = create(HARDNET_NAME, dataset="cityscapes", seed=3)
    direct.module.load_state_dict(flipped, strict=True)
    (x,) = loaded.example_inputs(*loaded.input_size)
    assert torch.equal(_logits(loaded, x), _logits(direct, x))
    converted = read_weights(path)
    assert converted.layout == FCHARDNET and converted.num_classes == 19
    assert len(converted.state) == HARDNET_OFFICIAL[0]
    assert converted.options == {"dataset": "cityscapes"}
    assert any("reversed" in note for note in converted.notes)


def test_fchardnet_rgb_input_gives_the_official_bgr_output(create, make_frame, hardnet_release):
    """evsmap's RGB pipeline with the converted file == the official network (the tensors
    renamed, first conv as released) on the official BGR pipeline; without the channel
    reversal the outputs differ."""
    path, state = hardnet_release
    loaded = create(HARDNET_NAME, dataset="cityscapes", weights=path)
    as_released = create(HARDNET_NAME, dataset="cityscapes")
    as_released.module.load_state_dict(state, strict=True)
    frame = make_frame(*loaded.input_size, seed=3)  # no resize
    reference = _logits(as_released, _bgr_pipeline(frame.rgb))
    ours = loaded.logits(loaded.preprocess(frame))
    scale = float(reference.abs().max())
    assert float((ours - reference).abs().max()) <= 1e-5 * max(scale, 1.0)
    unflipped = as_released.logits(as_released.preprocess(frame))
    assert float((unflipped - reference).abs().max()) > 1e-3 * scale


def test_fchardnet_class_mismatch_names_the_option(create, hardnet_release):
    path, _ = hardnet_release
    message = _error(lambda: create(HARDNET_NAME, weights=path))  # nyuv2: 40 classes
    assert "official FC-HarDNet release" in message and "19 classes" in message
    assert "-o dataset=cityscapes" in message


# ------------------------------------------------------------------------------------------
# the numpy allow-list
# ------------------------------------------------------------------------------------------


def _respell(path: Path, old: bytes, new: bytes) -> Path:
    """The same torch zip file with ``old`` replaced by ``new`` in its pickle (protocol 2 writes
    a global as text, so a module name can be changed in place)."""
    out = path.with_name("respelled_" + path.name)
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as dst:
        for info in src.infolist():
            data = src.read(info.filename)
            if info.filename.endswith("data.pkl"):
                data = data.replace(old, new)
            dst.writestr(info.filename, data)
    return out


@pytest.mark.parametrize("spelling", [b"numpy.core.multiarray", b"numpy._core.multiarray"])
def test_numpy_scalars_of_either_numpy_load(tmp_path, spelling):
    path = tmp_path / "meta.pth"
    torch.save({"epoch": 3, "model_state": {"w": torch.ones(2)}, "best_iou": np.float64(0.7)},
               path)
    raw = zipfile.ZipFile(path).read(next(n for n in zipfile.ZipFile(path).namelist()
                                          if n.endswith("data.pkl")))
    written = b"numpy._core.multiarray" if b"numpy._core.multiarray" in raw \
        else b"numpy.core.multiarray"
    respelled = _respell(path, written + b"\nscalar", spelling + b"\nscalar")
    obj = read_checkpoint(respelled)
    assert obj["best_iou"] == 0.7 and isinstance(obj["best_iou"], np.float64)


class _Tracked(OrderedDict):
    """A dict subclass: pickled by reference to this module, so never allowed."""


def _hook():  # a function reference in a file
    return None


@pytest.mark.parametrize("payload", [
    pytest.param(lambda s: _Tracked(s), id="OrderedDict-subclass"),
    pytest.param(lambda s: {"state_dict": s, "hook": _hook}, id="function"),
    pytest.param(lambda s: {"state_dict": s, "stats": np.zeros(3)}, id="numpy-array"),
    pytest.param(lambda s: {"state_dict": s, "iou": np.float32(0.5)}, id="numpy-float32"),
])
def test_allow_list_admits_nothing_else(create, tmp_path, payload):
    state = create(HARDNET_NAME).module.state_dict()
    path = tmp_path / "evil.pth"
    torch.save(payload(state), path)
    message = _error(lambda: create(HARDNET_NAME, weights=path))
    assert message.startswith(f"{path}: cannot read weights (")
    assert "weights_only" not in message and "\x1b" not in message


def test_allow_list_names_the_refused_global(tmp_path):
    path = tmp_path / "evil.pth"
    torch.save(_Tracked(a=torch.zeros(1)), path)
    message = _error(lambda: read_checkpoint(path))
    assert f"{__name__}._Tracked" in message and "may not hold" in message


# ------------------------------------------------------------------------------------------
# layouts
# ------------------------------------------------------------------------------------------


def test_plain_state_dict_with_no_known_key(create, tmp_path):
    path = tmp_path / "other.pth"
    torch.save({"backbone.conv.weight": torch.zeros(1)}, path)
    message = _error(lambda: create(HARDNET_NAME, weights=path))
    assert "no key of the file is a key of the network" in message
    assert "official ESANet release" in message and "official FC-HarDNet release" in message


def test_layout_detection():
    assert official.detect_layout(["encoder_rgb.conv1.weight", "decoder.conv_out.weight"]) \
        == ESANET
    assert official.detect_layout(["base.0.conv.weight", "finalConv.weight"]) == FCHARDNET
    assert official.detect_layout(["encoder.stem.0.0.weight"]) == PLAIN
    assert official.detect_layout(["encoder.stem.0.0.weight"], {"model": "x"}) == EVSMAP


def test_missing_batch_counters_are_filled(create):
    state = _perturbed(create(HARDNET_NAME, dataset="cityscapes").module, seed=1)
    theirs = {k: v for k, v in _to_official(state, fchardnet_table()).items()
              if not k.endswith("num_batches_tracked")}  # saved by PyTorch < 0.4.1
    converted = convert_state(theirs)
    assert len(converted.state) == HARDNET_OFFICIAL[0]
    assert any("num_batches_tracked" in note for note in converted.notes)


# ------------------------------------------------------------------------------------------
# evsmap weights convert
# ------------------------------------------------------------------------------------------


def _cli(capsys, *argv) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_convert_round_trip(create, capsys, tmp_path, hardnet_release):
    src, _ = hardnet_release
    dst = tmp_path / "out" / "fchardnet-70@cityscapes.pt"
    code, out, err = _cli(capsys, "weights", "convert", src, "--out", dst, "--json")
    assert code == 0, err
    card = json.loads(out)["card"]
    assert card["model"] == HARDNET_NAME and card["options"] == {"dataset": "cityscapes"}
    assert card["num_classes"] == 19 and len(card["class_names"]) == 19
    assert card["source_layout"] == FCHARDNET and card["source_file"] == src.name
    assert card["source_sha256"] == hashlib.sha256(src.read_bytes()).hexdigest()
    assert card["tensors"] == HARDNET_OFFICIAL[0] and card["card_version"] == 1
    assert card["evsmap_version"] and card["conversion"]

    obj = read_checkpoint(dst)  # a plain evsmap state dict plus the card
    assert set(obj) == {"state_dict", "card"} and obj["card"] == card
    assert tensors_sha256(obj["state_dict"]) == card["tensors_sha256"]
    converted = read_weights(dst)
    assert converted.layout == EVSMAP and converted.card == card

    from_release = create(HARDNET_NAME, dataset="cityscapes", weights=src)
    from_card = create(HARDNET_NAME, dataset="cityscapes", weights=dst)
    (x,) = from_card.example_inputs(*from_card.input_size)
    assert torch.equal(_logits(from_card, x), _logits(from_release, x))

    # the card is named when the file does not fit
    message = _error(lambda: create(HARDNET_NAME, weights=dst))
    assert "evsmap checkpoint" in message and "dataset=cityscapes" in message

    code, _, err = _cli(capsys, "weights", "convert", src, "--out", dst)
    assert code == 2 and "exists" in err and "--overwrite" in err and err.count("\n") == 1
    code, out, _ = _cli(capsys, "weights", "convert", dst, "--out", tmp_path / "again.pt")
    assert code == 0 and "wrote" in out and "-o dataset=cityscapes" in out
    assert read_checkpoint(tmp_path / "again.pt")["card"]["source_layout"] == EVSMAP


def test_convert_refuses_a_mismatch_in_one_line(capsys, tmp_path, esanet_release):
    src, _ = esanet_release("cityscapes")
    code, _, err = _cli(capsys, "weights", "convert", src, "--out", tmp_path / "x.pt",
                        "-o", "dataset=nyuv2")
    assert code == 2 and err.count("\n") == 1
    assert "evsmap weights: error:" in err and "-o dataset=cityscapes" in err
    assert not (tmp_path / "x.pt").exists()


def test_convert_plain_needs_a_model(capsys, create, tmp_path):
    src = tmp_path / "plain.pth"
    torch.save(create(HARDNET_NAME).module.state_dict(), src)
    code, _, err = _cli(capsys, "weights", "convert", src, "--out", tmp_path / "x.pt")
    assert code == 2 and "--model NAME" in err and err.count("\n") == 1
    code, out, err = _cli(capsys, "weights", "convert", src, "--out", tmp_path / "x.pt",
                          "--model", HARDNET_NAME, "--json")
    assert code == 0, err
    card = json.loads(out)["card"]
    assert card["source_layout"] == PLAIN and card["options"] == {}


def test_weights_command_starts_without_torch():
    probe = ("import sys\nfrom evsmap.cli.main import main\n"
             "try:\n    main(['weights', 'convert', '--help'])\n"
             "except SystemExit:\n    pass\n"
             "print('torch' in sys.modules, file=sys.stderr)")
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=120)
    assert "SRC" in proc.stdout
    assert proc.stderr.strip().splitlines()[-1] == "False"


def test_card_is_plain_data(tmp_path):
    # what the card may hold reads back with weights_only=True and no allow-list at all
    card = {"card_version": 1, "options": {"dataset": "cityscapes"}, "class_names": ["a"],
            "tensors": 1, "ok": True, "x": 0.5}
    buf = io.BytesIO()
    torch.save({"state_dict": {"w": torch.zeros(1)}, "card": card}, buf)
    buf.seek(0)
    assert torch.load(buf, weights_only=True)["card"] == card
