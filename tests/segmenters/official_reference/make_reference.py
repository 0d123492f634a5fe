"""Regenerate the official networks' predictions that ``test_official_predictions.py`` compares
``evsmap predict`` with. Needs the official code checked out (not shipped with evsmap):

    python tests/segmenters/official_reference/make_reference.py \
        --esanet PATH/TO/TUI-NICR/ESANet --fchardnet PATH/TO/PingoLH/FCHarDNet \
        --samples ../shared/data/nyuv2_samples

For each network it builds the official model (``ESANet(...)`` of ``src/models/model.py`` in the
NYUv2 release configuration; ``hardnet(n_classes=19)`` of ``ptsemseg/models/hardnet.py``, the
Cityscapes release), loads the seeded tensors of :mod:`release_state` strictly, and predicts every
sample with the official inference steps, written out here because the official preprocessing
imports torchvision (which evsmap cannot install on CPU):

* ESANet, ``inference_samples.py``: RGB / 255 standardised with the ImageNet statistics; depth
  in millimetres (the files ESANet prepares for NYUv2) standardised with NYUv2's
  2841.94941272766 +- 1417.2594281672277, invalid (0) pixels set back to 0 - the 'raw' depth
  mode, as the official README runs ``inference_samples.py`` (``--raw_depth``); logits resized
  bilinearly to the image size; argmax.
* FC-HarDNet, ``test.py`` ``process_img``: the image as OpenCV reads it (BGR), cast to float16,
  ``(x - 255 mean) / (255 std)`` with the statistics in BGR order; argmax.

The samples are used at their own 480x640 size (both official scripts' resize is then the
identity). Writes ``<network>/<stem>.png`` (uint8 class ids) and ``reference.json``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import types
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from release_state import SEED, release_tensors, shapes_of  # noqa: E402

NYU_DEPTH_MM = (2841.94941272766, 1417.2594281672277)
IMAGENET = ((0.485, 0.456, 0.406), (0.229, 0.224, 0.225))
NYU_PNG_PER_METRE = 5000.0  # ../shared/data/nyuv2_samples: metres = value / 5000


def _esanet(root: Path) -> torch.nn.Module:
    sys.path.insert(0, str(root))
    from src.models.model import ESANet

    return ESANet(height=480, width=640, num_classes=40, encoder_rgb="resnet34",
                  encoder_depth="resnet34", encoder_block="NonBottleneck1D",
                  channels_decoder=[512, 256, 128], pretrained_on_imagenet=False,
                  context_module="ppm", nr_decoder_blocks=[3, 3, 3],
                  upsampling="learned-3x3-zeropad")


def _fchardnet(root: Path) -> torch.nn.Module:
    # hardnet.py imports an optional CUDA extension it does not use for inference
    stub = types.ModuleType("CatConv2d.catconv2d")
    stub.CatConv2d = object
    sys.modules.setdefault("CatConv2d", types.ModuleType("CatConv2d"))
    sys.modules.setdefault("CatConv2d.catconv2d", stub)
    spec = importlib.util.spec_from_file_location(
        "official_hardnet", root / "ptsemseg" / "models" / "hardnet.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.hardnet(n_classes=19)


def _load(model: torch.nn.Module) -> torch.nn.Module:
    model.load_state_dict(release_tensors(shapes_of(model.state_dict())), strict=True)
    return model.eval()


def esanet_predict(model, rgb: np.ndarray, depth_png: np.ndarray) -> np.ndarray:
    image = torch.from_numpy(rgb.transpose(2, 0, 1).astype(np.float32)) / 255
    mean, std = (torch.tensor(v).view(3, 1, 1) for v in IMAGENET)
    image = (image - mean) / std
    depth_mm = depth_png.astype(np.float32) * np.float32(1000.0 / NYU_PNG_PER_METRE)
    depth = (torch.from_numpy(depth_mm)[None] - NYU_DEPTH_MM[0]) / NYU_DEPTH_MM[1]
    depth[torch.from_numpy(depth_mm)[None] == 0] = 0  # depth_mode 'raw'
    with torch.no_grad():
        pred = model(image[None], depth[None])
    pred = F.interpolate(pred, rgb.shape[:2], mode="bilinear", align_corners=False)
    return pred.argmax(1)[0].numpy().astype(np.uint8)


def fchardnet_predict(model, rgb: np.ndarray) -> np.ndarray:
    img = rgb[:, :, ::-1].astype(np.float16)  # cv2.imread's BGR
    mean = [v * 255 for v in (0.406, 0.456, 0.485)]
    std = [v * 255 for v in (0.225, 0.224, 0.229)]
    img = (img - mean) / std
    x = torch.from_numpy(np.expand_dims(img.transpose(2, 0, 1), 0)).float()
    with torch.no_grad():
        pred = model(x)
    return pred.argmax(1)[0].numpy().astype(np.uint8)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--esanet", type=Path, required=True)
    ap.add_argument("--fchardnet", type=Path, required=True)
    ap.add_argument("--samples", type=Path, required=True)
    args = ap.parse_args()
    torch.set_num_threads(2)
    stems = sorted(p.stem for p in (args.samples / "rgb").glob("*.png"))
    networks = {"esanet-nyuv2": _load(_esanet(args.esanet)),
                "fchardnet-cityscapes": _load(_fchardnet(args.fchardnet))}
    summary: dict[str, object] = {"seed": SEED, "samples": stems, "torch": torch.__version__,
                                  "classes_predicted": {}}
    for name, model in networks.items():
        (HERE / name).mkdir(exist_ok=True)
        for stem in stems:
            rgb = np.asarray(Image.open(args.samples / "rgb" / f"{stem}.png").convert("RGB"))
            if name.startswith("esanet"):
                depth = np.asarray(Image.open(args.samples / "depth" / f"{stem}.png"))
                labels = esanet_predict(model, rgb, depth)
            else:
                labels = fchardnet_predict(model, rgb)
            Image.fromarray(labels).save(HERE / name / f"{stem}.png")
            summary["classes_predicted"][f"{name}/{stem}"] = int(len(np.unique(labels)))
            print(name, stem, "classes predicted:", len(np.unique(labels)))
    (HERE / "reference.json").write_text(json.dumps(summary, indent=2) + "\n")


if __name__ == "__main__":
    main()
