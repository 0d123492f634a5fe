"""A torch segmentation network wrapped as a :class:`~evsmap.interfaces.Segmenter`.

Every registered network (FEAGNet variants, ESANet, FC-HarDNet) is a :class:`NetworkSegmenter`:
it normalises a :class:`~evsmap.data.Frame` the way the network was trained, resizes it to the
network's input size, runs the network with torch (eval, inference mode) or ONNX Runtime (CPU,
through a cached single-file export), and returns the per-pixel top-k classes and probabilities
at the frame's resolution.
"""

from __future__ import annotations

import time
from os import PathLike
from typing import ClassVar

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from evsmap.data import Frame, SemanticObservation
from evsmap.errors import InvalidDataError, UnknownNameError
from evsmap.interfaces import Segmenter
from evsmap.segmenters.normalization import (  # noqa: F401  (re-exported)
    IMAGENET_MEAN,
    IMAGENET_STD,
    INDOOR,
    Normalization,
)
from evsmap.segmenters.weights import load_weights

BACKENDS = ("torch", "onnxruntime")


def network_inputs(rgb: np.ndarray, depth: np.ndarray | None, normalization: Normalization,
                   size: tuple[int, int]) -> tuple[torch.Tensor, ...]:
    """Normalised network inputs (batch 1, float32) at ``size`` (H, W): ``(rgb,)`` or
    ``(rgb, depth)`` when ``depth`` is given.

    ``rgb`` (``uint8`` HxWx3) is scaled to [0, 1], resized bilinearly and standardised per
    channel; ``depth`` (in the normalisation's depth units - see
    :meth:`Normalization.encode_depth` - 0 = invalid) is resized by nearest neighbour and
    standardised, invalid pixels set to 0. What :meth:`NetworkSegmenter.preprocess` feeds the
    network, and what training feeds it at the randomly scaled size (:mod:`evsmap.train.data`).
    """
    n = normalization
    size = tuple(size)
    rgb_t = torch.from_numpy(np.array(rgb, copy=True)).permute(2, 0, 1)[None].float()
    rgb_t = rgb_t / 255.0
    if tuple(rgb_t.shape[-2:]) != size:
        rgb_t = F.interpolate(rgb_t, size=size, mode="bilinear", align_corners=False)
    mean = torch.tensor(n.rgb_mean).view(1, 3, 1, 1)
    std = torch.tensor(n.rgb_std).view(1, 3, 1, 1)
    rgb_t = (rgb_t - mean) / std
    if depth is None:
        return (rgb_t,)
    depth_t = torch.from_numpy(np.array(depth, copy=True))[None, None]
    if tuple(depth_t.shape[-2:]) != size:
        depth_t = F.interpolate(depth_t, size=size, mode="nearest")
    valid = depth_t > 0
    depth_t = torch.where(valid, (depth_t - n.depth_mean) / n.depth_std, torch.zeros(()))
    return rgb_t, depth_t


def as_size(value: object, what: str = "input_size") -> tuple[int, int]:
    """(height, width) from a pair of positive integers or a ``HxW`` string (``-o
    input_size=240x320``).

    Raises:
        InvalidDataError: anything else (names ``what`` and the value).
    """
    parts = value
    if isinstance(value, str):
        h, sep, w = value.lower().partition("x")
        parts = (h, w) if sep else ()
    try:
        size = tuple(int(v) for v in parts)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        size = ()
    if len(size) != 2 or min(size) < 1:
        raise InvalidDataError(f"{what} must be HEIGHTxWIDTH in pixels (e.g. 480x640), "
                               f"got {value!r}")
    return size  # type: ignore[return-value]


def seeded_inputs(uses_depth: bool, height: int, width: int) -> tuple[torch.Tensor, ...]:
    """Inputs drawn from seed 0 for a network of these inputs (batch 1): an RGB tensor
    (1, 3, H, W), then a depth tensor (1, 1, H, W) for an RGB-D network. The same in every
    process, so an export and its timing (``evsmap speed``, ``evsmap gate``) see one input."""
    gen = torch.Generator().manual_seed(0)
    rgb = torch.randn(1, 3, height, width, generator=gen)
    if not uses_depth:
        return (rgb,)
    return rgb, torch.randn(1, 1, height, width, generator=gen)


class NetworkSegmenter(Segmenter):
    """A segmentation network as a segmenter plug-in.

    Args:
        name: registered name (used in messages and as the ONNX cache key).
        module: the network; ``module(rgb)`` or ``module(rgb, depth)`` returns logits
            (B, C, H, W) in eval mode.
        num_classes: number of classes the network predicts.
        class_names: one name per class.
        uses_depth: whether the network reads depth.
        default_size: (H, W) the paper measures the network at; also the input size when
            ``input_size`` is not given.
        normalization: input normalisation.
        backend: ``"torch"`` or ``"onnxruntime"``.
        weights: optional state-dict file to load.
        input_size: (H, W) frames are resized to before the network (default ``default_size``).
        config: the factory's options (recorded, and part of the ONNX cache key).
    """

    uses_depth: ClassVar[bool] = True  # overridden per instance

    def __init__(
        self,
        *,
        name: str,
        module: nn.Module,
        num_classes: int,
        class_names: tuple[str, ...],
        uses_depth: bool,
        default_size: tuple[int, int],
        normalization: Normalization = INDOOR,
        backend: str = "torch",
        weights: str | PathLike[str] | None = None,
        input_size: tuple[int, int] | None = None,
        config: dict | None = None,
    ) -> None:
        if backend not in BACKENDS:
            raise UnknownNameError(
                f"unknown backend {backend!r} (known: {', '.join(BACKENDS)})")
        if len(class_names) != num_classes:
            raise InvalidDataError(
                f"{name}: {len(class_names)} class names for {num_classes} classes")
        self.name = name
        self._module = module.eval()
        self.num_classes = num_classes
        self.class_names = tuple(class_names)
        self.uses_depth = uses_depth  # type: ignore[misc]
        self.default_size = tuple(default_size)
        self.normalization = normalization
        self.backend = backend
        self.input_size = (as_size(input_size, f"{name}: input_size")
                           if input_size is not None else self.default_size)
        self.config = dict(config or {})
        self.weights = str(weights) if weights is not None else None
        if weights is not None:
            load_weights(self._module, weights)
        self._session = None
        self.last_timings: dict[str, float] = {}
        """Milliseconds of the last :meth:`predict`'s stages: ``preprocess`` (normalise,
        resize), ``network`` (the forward pass on the backend), ``postprocess`` (upsampling,
        top-k and probabilities)."""

    @property
    def module(self) -> nn.Module:
        return self._module

    @property
    def input_names(self) -> tuple[str, ...]:
        return ("rgb", "depth") if self.uses_depth else ("rgb",)

    def example_inputs(self, height: int, width: int) -> tuple[torch.Tensor, ...]:
        """Deterministic random inputs of the network's shapes (batch 1)."""
        return seeded_inputs(self.uses_depth, height, width)

    # -- preprocessing ---------------------------------------------------------------------

    def preprocess(self, frame: Frame) -> tuple[torch.Tensor, ...]:
        """Normalised, resized network inputs (batch 1, float32) for ``frame``."""
        frame.require_images(f"segmenter {self.name!r}")
        depth = self.normalization.encode_depth(frame.depth, frame) if self.uses_depth \
            else None
        return network_inputs(frame.rgb, depth, self.normalization, self.input_size)

    # -- inference -------------------------------------------------------------------------

    def logits(self, inputs: tuple[torch.Tensor, ...]) -> torch.Tensor:
        """Raw network output for preprocessed ``inputs`` with the configured backend."""
        if self.backend == "torch":
            with torch.inference_mode():
                return self._module(*inputs)
        session = self._ort_session(inputs)
        feed = {name: t.numpy() for name, t in zip(self.input_names, inputs, strict=True)}
        return torch.from_numpy(session.run(None, feed)[0])

    def _ort_session(self, inputs: tuple[torch.Tensor, ...]):
        if self._session is None:
            import onnxruntime as ort

            from evsmap.models.onnx_export import cached_onnx

            key = f"{self.name}:{sorted(self.config.items())}"
            path = cached_onnx(self._module, inputs, self.input_names, key=key)
            options = ort.SessionOptions()
            options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
            options.intra_op_num_threads = torch.get_num_threads()
            self._session = ort.InferenceSession(str(path), options,
                                                 providers=["CPUExecutionProvider"])
        return self._session

    def predict(self, frame: Frame, *, k: int = 3) -> SemanticObservation:
        if not 1 <= k <= self.num_classes:
            raise InvalidDataError(f"k must lie in [1, {self.num_classes}], got {k}")
        t0 = time.perf_counter()
        inputs = self.preprocess(frame)
        t1 = time.perf_counter()
        logits = self.logits(inputs)
        t2 = time.perf_counter()
        observation = self.top_k(logits, frame.rgb.shape[:2], k)
        t3 = time.perf_counter()
        self.last_timings = {"preprocess": (t1 - t0) * 1e3, "network": (t2 - t1) * 1e3,
                             "postprocess": (t3 - t2) * 1e3}
        return observation

    def top_k(self, logits: torch.Tensor, size: tuple[int, int], k: int) -> SemanticObservation:
        """The per-pixel top-``k`` classes and softmax probabilities of ``logits`` (1, C, h, w)
        at the frame's ``size`` (bilinear upsampling of the logits first when they differ)."""
        h, w = size
        if tuple(logits.shape[-2:]) != (h, w):
            logits = F.interpolate(logits, size=(h, w), mode="bilinear", align_corners=False)
        from evsmap.segmenters.topk import top_k_softmax

        classes, probs = top_k_softmax(logits[0], k)
        return SemanticObservation(classes=classes, probs=probs, num_classes=self.num_classes)
