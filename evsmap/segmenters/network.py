"""A torch segmentation network wrapped as a :class:`~evsmap.interfaces.Segmenter`.

Every registered network (FEAGNet variants, ESANet, FC-HarDNet) is a :class:`NetworkSegmenter`:
it normalises a :class:`~evsmap.data.Frame` the way the network was trained, resizes it to the
network's input size, runs the network with torch (eval, inference mode) or ONNX Runtime (CPU,
through a cached single-file export; ``precision="int8"``: its static QDQ quantisation, see
:meth:`NetworkSegmenter.calibrate` and :mod:`evsmap.segmenters.quantize`), and returns the
per-pixel top-k classes and probabilities at the frame's resolution.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from os import PathLike
from typing import TYPE_CHECKING, ClassVar

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from evsmap.data import Frame, SemanticObservation
from evsmap.errors import EvsmapError, InvalidDataError, UnknownNameError
from evsmap.interfaces import Segmenter
from evsmap.segmenters.normalization import (  # noqa: F401  (re-exported)
    IMAGENET_MEAN,
    IMAGENET_STD,
    INDOOR,
    Normalization,
)
from evsmap.segmenters.weights import load_weights

if TYPE_CHECKING:
    from evsmap.segmenters.quantize import QuantizedModel

BACKENDS = ("torch", "onnxruntime")
PRECISIONS = ("fp32", "fp16", "bf16", "int8")
AUTOCAST_PRECISIONS = ("fp16", "bf16")
"""Precisions run by torch's mixed precision (``torch.autocast``), on the torch backend."""
POSTPROCESSES = ("network", "fused", "stride")
"""How logits become the observation (``postprocess``): ``network`` - the network resizes its
logits to the input size, then the top-k and softmax of every pixel (the faithful path);
``fused`` - the network returns its logits at its output stride and the bilinear resize runs
inside the top-k, block by block, at the pixels the map reads only (the same arithmetic up to
float32 rounding: the same labels); ``stride`` - the top-k at the output stride, the observation
resized by nearest neighbour (a named variant: labels change along class boundaries)."""


def network_inputs(rgb: np.ndarray, depth: np.ndarray | None, normalization: Normalization,
                   size: tuple[int, int]) -> tuple[torch.Tensor, ...]:
    """Normalised network inputs (batch 1, float32) at ``size`` (H, W): ``(rgb,)`` or
    ``(rgb, depth)`` when ``depth`` is given.

    ``rgb`` (``uint8`` HxWx3) is scaled to [0, 1], resized bilinearly
    (:func:`evsmap.segmenters.resize.bilinear`: the same bits whatever the thread count) and
    standardised per channel; ``depth`` (in the normalisation's depth units - see
    :meth:`Normalization.encode_depth` - 0 = invalid) is resized by nearest neighbour and
    standardised, invalid pixels set to 0. What :meth:`NetworkSegmenter.preprocess` feeds the
    network, and what training feeds it at the randomly scaled size (:mod:`evsmap.train.data`).
    """
    n = normalization
    height, width = size
    size = (height, width)
    # channels first and contiguous, scaled, then resized by evsmap's own kernel: torch's
    # bilinear kernel rounds differently with one thread than with more (resize.py)
    chw = np.ascontiguousarray(np.asarray(rgb).transpose(2, 0, 1), dtype=np.float32)
    chw /= np.float32(255.0)
    if chw.shape[-2:] != size:
        from evsmap.segmenters.resize import bilinear  # numba: loaded only where a frame resizes

        chw = bilinear(chw, size)
    rgb_t = torch.from_numpy(chw)[None]
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
    size: tuple[int, ...] = ()
    if isinstance(parts, Iterable):
        try:
            size = tuple(int(v) for v in parts)
        except (TypeError, ValueError):
            size = ()
    if len(size) != 2 or min(size) < 1:
        raise InvalidDataError(f"{what} must be HEIGHTxWIDTH in pixels (e.g. 480x640), "
                               f"got {value!r}")
    return size[0], size[1]


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
        precision: ``"fp32"``, ``"fp16"`` or ``"bf16"`` (torch's autocast at that dtype, torch
            backend only) or ``"int8"``. int8 runs only on ONNX Runtime (``backend="torch"``
            with int8 is refused, not switched) and needs :meth:`calibrate` before the first
            :meth:`predict`, which otherwise raises.
        int8_scheme: ``"auto"`` (default: the scheme exact on this machine's instruction
            set, :func:`evsmap.segmenters.quantize.auto_scheme`) or one of
            :data:`evsmap.segmenters.quantize.SCHEMES`, used by :meth:`calibrate`.
        postprocess: one of :data:`POSTPROCESSES` (default ``network``); ``fused`` and
            ``stride`` need a :class:`~evsmap.models.layers.StridedLogits` network (FEAGNet)
            and change what :meth:`logits` returns (the logits at the output stride).
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
        precision: str = "fp32",
        int8_scheme: str = "auto",
        postprocess: str = "network",
    ) -> None:
        if postprocess not in POSTPROCESSES:
            raise UnknownNameError(f"{name}: unknown postprocess {postprocess!r} (known: "
                                   f"{', '.join(POSTPROCESSES)})")
        if postprocess != "network":
            from evsmap.models.layers import StridedLogits

            if not isinstance(module, StridedLogits):
                raise InvalidDataError(f"{name}: postprocess={postprocess} needs a network "
                                       f"that can return its logits before the final resize "
                                       f"(FEAGNet); {name} cannot: use postprocess=network")
            module.upsample_logits = False
        self.postprocess = postprocess
        if backend not in BACKENDS:
            raise UnknownNameError(
                f"unknown backend {backend!r} (known: {', '.join(BACKENDS)})")
        self.backend = backend
        self._check_precision(name, precision, int8_scheme)
        self.precision = precision
        self.int8_scheme = int8_scheme
        """The scheme asked for (``auto`` or a name) until :meth:`calibrate`, then the one
        used."""
        self.int8_scheme_chosen_by = ""
        """After :meth:`calibrate`: ``"given"`` or ``"auto for <instruction set>"``."""
        self.quantization: QuantizedModel | None = None
        """The int8 model in use (settings, nodes kept in fp32, calibration) once
        :meth:`calibrate` ran; None before and for fp32."""
        if len(class_names) != num_classes:
            raise InvalidDataError(
                f"{name}: {len(class_names)} class names for {num_classes} classes")
        self.name = name
        self._module = module.eval()
        self.num_classes = num_classes
        self.class_names = tuple(class_names)
        self.uses_depth = uses_depth  # type: ignore[misc]
        height, width = default_size
        self.default_size: tuple[int, int] = (height, width)
        self.normalization = normalization
        self.input_size: tuple[int, int] = (as_size(input_size, f"{name}: input_size")
                           if input_size is not None else self.default_size)
        self.config = dict(config or {})
        self.weights = str(weights) if weights is not None else None
        if weights is not None:
            load_weights(self._module, weights)
        self._session = None
        self.device = "cpu"
        """Where the network runs (:meth:`place`): ``cpu`` or ``cuda:N``."""
        self._int8_size: tuple[int, int] | None = None
        self._threads: int | None = None
        self._ort_spinning = True
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
        assert frame.rgb is not None and frame.depth is not None  # an image frame
        depth = self.normalization.encode_depth(frame.depth, frame) if self.uses_depth \
            else None
        return network_inputs(frame.rgb, depth, self.normalization, self.input_size)

    # -- inference -------------------------------------------------------------------------

    def set_input_size(self, size: tuple[int, int]) -> None:
        """Resize frames to ``size`` (H, W) from the next :meth:`predict` on (an ONNX Runtime
        session is built for one input shape: the next call builds another)."""
        self.input_size = as_size(size, f"{self.name}: input_size")
        self._session = None

    def place(self, *, device: str = "cpu", precision: str | None = None) -> None:
        """Run the network on ``device`` (``cpu``, ``cuda[:N]``; :mod:`evsmap.devices`) and,
        with ``precision``, at that precision (``fp16``/``bf16``: autocast, torch backend).

        On a GPU the torch backend's logits stay there and the faithful post-processing
        (resize, softmax, top-k) runs there too, so only the top-k crosses to the host; the
        ``fused`` and ``stride`` paths take the logits at the output stride to the host (a
        sixteenth of the pixels) and run their CPU kernels. ONNX Runtime runs on its CUDA
        provider there (``evsmap[gpu]``).

        Raises:
            UnknownNameError, DeviceUnavailableError: the device (:func:`evsmap.devices.
                require_device`) or the CUDA provider is not there.
            InvalidDataError: int8 on a GPU, autocast on ONNX Runtime.
        """
        from evsmap.devices import require_device

        target = require_device(device)
        if precision is not None:
            self._check_precision(self.name, precision, self.int8_scheme)
            self.precision = precision
        if target.type == "cuda" and self.precision == "int8":
            raise InvalidDataError(f"{self.name}: int8 here is ONNX Runtime's CPU quantisation; "
                                   f"on a GPU use --precision fp16 or bf16")
        if target.type == "cuda" and self.backend == "onnxruntime":
            from evsmap.models.ort_providers import provider_chain

            provider_chain("cuda", device_index=target.index or 0)  # refuses when absent
        if self.backend == "torch":  # ONNX Runtime exports the module from the host
            self._module.to(target)
        self.device = str(target)
        self._session = None

    def logits(self, inputs: tuple[torch.Tensor, ...]) -> torch.Tensor:
        """Raw network output for preprocessed ``inputs`` with the configured backend (on
        :attr:`device` for the torch backend; float32, or the autocast dtype)."""
        if self.backend == "torch":
            with self._torch_threads(), torch.inference_mode(), self._autocast():
                return self._module(*(t.to(self.device, non_blocking=True) for t in inputs))
        session = self._ort_session(inputs)
        feed = {name: t.numpy() for name, t in zip(self.input_names, inputs, strict=True)}
        return torch.from_numpy(session.run(None, feed)[0])

    def _torch_threads(self):
        """torch's intra-op threads for the forward pass on the CPU: :meth:`set_threads`'s
        count when one was set (torch's convolutions choose their algorithm and split their
        work by the thread count, so the logits depend on it), else a context doing nothing."""
        import contextlib

        if self._threads is None or self.device != "cpu" \
                or self._threads == torch.get_num_threads():
            return contextlib.nullcontext()
        from evsmap.models.module_utils import torch_threads

        return torch_threads(self._threads)

    def _autocast(self):
        """``torch.autocast`` at the precision's dtype, or a context doing nothing."""
        import contextlib

        if self.precision not in AUTOCAST_PRECISIONS:
            return contextlib.nullcontext()
        dtype = torch.float16 if self.precision == "fp16" else torch.bfloat16
        return torch.autocast(device_type=torch.device(self.device).type, dtype=dtype)

    def _check_precision(self, name: str, precision: str, scheme: str) -> None:
        from evsmap.segmenters.quantize import AUTO, SCHEMES

        if precision not in PRECISIONS:
            raise UnknownNameError(
                f"unknown precision {precision!r} (known: {', '.join(PRECISIONS)})")
        if scheme != AUTO and scheme not in SCHEMES:
            raise UnknownNameError(
                f"unknown int8 scheme {scheme!r} (known: {AUTO}, {', '.join(SCHEMES)})")
        if precision == "int8" and self.backend != "onnxruntime":
            raise InvalidDataError(f"{name}: int8 runs on ONNX Runtime only: pass "
                                   f"backend='onnxruntime' (backend {self.backend!r} given)")
        if precision in AUTOCAST_PRECISIONS and self.backend != "torch":
            raise InvalidDataError(f"{name}: {precision} is torch's autocast: it runs on the "
                                   f"torch backend only (backend {self.backend!r} given)")

    def _fp32_onnx(self, inputs: tuple[torch.Tensor, ...],
                   cache_dir: str | PathLike[str] | None = None):
        from evsmap.models.onnx_export import cached_onnx

        key = f"{self.name}:{sorted(self.config.items())}"
        if self.postprocess != "network":  # a graph without the final resize
            key += ":logits at the output stride"
        return cached_onnx(self._module, inputs, self.input_names, key=key,
                           cache_dir=cache_dir)

    def calibrate(self, frames, *, scheme: str | None = None, method: str = "minmax",
                  auto_exclude: int = 0, source: str = "",
                  cache_dir: str | PathLike[str] | None = None) -> QuantizedModel:
        """Quantise the network to int8 with ``frames`` as the calibration set and run int8
        from now on (``precision`` becomes ``"int8"``).

        The frames are preprocessed as :meth:`predict` does (at :attr:`input_size`) and fed to
        :func:`evsmap.segmenters.quantize.quantize_model`, which caches the result by the fp32
        export, the calibration inputs and the settings.

        Args:
            frames: calibration frames (any iterable of :class:`~evsmap.data.Frame`).
            scheme: ``"auto"`` or one of :data:`~evsmap.segmenters.quantize.SCHEMES` (default
                :attr:`int8_scheme`); ``auto`` is resolved for this machine's instruction set.
            method: calibration method (:data:`evsmap.segmenters.quantize.METHODS`).
            auto_exclude: keep in fp32 the nodes around this many tensors of worst
                quantisation SQNR on the calibration frames (0: the rules only).
            source: what the frames are, recorded in the cache's sidecar.
            cache_dir: cache folder (default: the ONNX export cache).

        Raises:
            InvalidDataError: the backend is not onnxruntime, or no frame was given.
        """
        from evsmap.segmenters.quantize import Int8Settings, quantize_model, resolve_scheme

        scheme = self.int8_scheme if scheme is None else scheme
        self._check_precision(self.name, "int8", scheme)
        scheme, chosen_by = resolve_scheme(scheme)
        settings = Int8Settings(scheme=scheme, method=method, auto_exclude=auto_exclude)
        inputs = [self.preprocess(frame) for frame in frames]
        if not inputs:
            raise InvalidDataError(f"{self.name}: int8 calibration needs at least one frame")
        fp32 = self._fp32_onnx(inputs[0], cache_dir)
        feeds = [{n: t.numpy() for n, t in zip(self.input_names, x, strict=True)}
                 for x in inputs]
        self.quantization = quantize_model(
            fp32_path=fp32, calibration=feeds, settings=settings, cache_dir=cache_dir,
            stem=self.name, source=source)
        self.precision, self.int8_scheme = "int8", scheme
        self.int8_scheme_chosen_by = chosen_by
        self._int8_size = self.input_size
        self._session = None
        return self.quantization

    def precision_record(self) -> dict:
        """``precision``, ``postprocess`` (where not the faithful ``network``), ``device`` (where
        not the CPU) and, for int8, the scheme and how the model was made (for records)."""
        post = {} if self.postprocess == "network" else {"postprocess": self.postprocess}
        if self.device != "cpu":
            post["device"] = self.device
        if self.precision != "int8":
            return {"precision": self.precision, **post}
        q = self.quantization
        return {"precision": "int8", **post, "int8_scheme": self.int8_scheme,
                "int8_scheme_chosen_by": self.int8_scheme_chosen_by,
                "instruction_set": None if q is None else q.instruction_set,
                "int8": None if q is None else {
                    "method": q.settings["method"], "calibration_frames": q.calibration_frames,
                    "calibration_source": q.calibration_source,
                    "auto_exclude": q.settings["auto_exclude"],
                    "fp32_nodes": len(q.excluded), "model": q.path.name, "cached": q.cached}}

    def _model_path(self, inputs: tuple[torch.Tensor, ...]):
        if self.precision != "int8":
            return self._fp32_onnx(inputs)
        if self.quantization is None:
            raise EvsmapError(f"{self.name}: int8 needs calibrating first (segmenter."
                              f"calibrate(frames); the CLI calibrates on "
                              f"--calibration-frames frames)")
        if self.input_size != self._int8_size:
            assert self._int8_size is not None  # set with self.quantization
            h, w = self._int8_size
            raise EvsmapError(f"{self.name}: the int8 model was calibrated at {h}x{w}, not "
                              f"{self.input_size[0]}x{self.input_size[1]}: calibrate again")
        return self.quantization.path

    def _ort_session(self, inputs: tuple[torch.Tensor, ...]):
        if self._session is None:
            import onnxruntime as ort

            path = self._model_path(inputs)
            options = ort.SessionOptions()
            options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
            options.intra_op_num_threads = self._threads or torch.get_num_threads()
            options.add_session_config_entry("session.intra_op.allow_spinning",
                                             "1" if self._ort_spinning else "0")
            from evsmap.models.ort_providers import check_used, default_provider, provider_chain

            provider = default_provider(self.device)
            index = torch.device(self.device).index or 0
            self._session = ort.InferenceSession(
                str(path), options, providers=provider_chain(provider, device_index=index))
            check_used(self._session, provider)
        return self._session

    def set_threads(self, threads: int | None = None, *, spinning: bool = True) -> dict:
        """The network's intra-op threads (``None``: torch's thread count at each call, as
        before): ONNX Runtime's pool, with its spinning (``session.intra_op.allow_spinning``;
        the session is rebuilt on the next call when either changes), or torch's threads for
        the forward pass alone (set and restored around it; pre- and post-processing keep
        torch's threads of the moment, and give the same bits whatever they are). The logits
        depend on this count (docs/cli.md, "Thread independence"); nothing else does.

        Returns what the network uses now: ``{"onnxruntime": n, "spinning": b}`` or
        ``{"network": n}`` (the torch backend)."""
        if threads is not None and (isinstance(threads, bool) or int(threads) < 1):
            raise InvalidDataError(f"{self.name}: threads must be a positive integer, got "
                                   f"{threads!r}")
        threads = None if threads is None else int(threads)
        if (threads, spinning) != (self._threads, self._ort_spinning):
            self._threads, self._ort_spinning = threads, bool(spinning)
            self._session = None
        if self.backend != "onnxruntime":
            return {"network": self._threads or torch.get_num_threads()}
        return {"onnxruntime": self._threads or torch.get_num_threads(),
                "spinning": self._ort_spinning}

    @property
    def network_threads(self) -> int:
        """The intra-op threads the network's next forward pass runs with (:meth:`set_threads`,
        else torch's count of the moment): the one setting its logits depend on."""
        return self._threads or torch.get_num_threads()

    def predict(self, frame: Frame, *, k: int = 3) -> SemanticObservation:
        return self.predict_at(frame, None, k=k)

    def predict_at(self, frame: Frame, pixels: np.ndarray | None, *, k: int = 3
                   ) -> SemanticObservation:
        """:meth:`predict`; with ``postprocess="fused"`` only ``pixels`` (bool HxW) are
        post-processed (the others: class 0, probability 0)."""
        if not 1 <= k <= self.num_classes:
            raise InvalidDataError(f"k must lie in [1, {self.num_classes}], got {k}")
        t0 = time.perf_counter()
        inputs = self.preprocess(frame)
        t1 = time.perf_counter()
        logits = self.logits(inputs)
        if logits.is_cuda:  # the stage's time is the GPU's, not the launch's
            torch.cuda.synchronize(logits.device)
        t2 = time.perf_counter()
        assert frame.rgb is not None  # preprocess checked that it is an image frame
        observation = self.top_k(logits, frame.rgb.shape[:2], k, pixels)
        t3 = time.perf_counter()
        self.last_timings = {"preprocess": (t1 - t0) * 1e3, "network": (t2 - t1) * 1e3,
                             "postprocess": (t3 - t2) * 1e3}
        return observation

    def top_k(self, logits: torch.Tensor, size: tuple[int, int], k: int,
              pixels: np.ndarray | None = None) -> SemanticObservation:
        """The per-pixel top-``k`` classes and softmax probabilities of ``logits`` (1, C, h, w,
        what :meth:`logits` returned) at the frame's ``size``, as :attr:`postprocess` says:
        ``network`` - bilinear upsampling of the logits first when they differ from ``size``
        (on the host by :func:`~evsmap.segmenters.resize.bilinear`, thread-independent);
        ``fused`` - the network's own resize to its input size inside the top-k
        (:func:`~evsmap.segmenters.topk.top_k_upsampled`, at ``pixels`` only, a bool mask;
        resized in two steps as ``network`` would when the input size is not the frame's);
        ``stride`` - the top-k at the output stride, resized by nearest neighbour."""
        from evsmap.segmenters import topk

        h, w = size
        if logits.is_cuda and self.postprocess == "network":
            return _top_k_on_device(logits, size, k, self.num_classes)
        logits = logits.float().cpu()
        if self.postprocess == "stride":
            classes, probs = topk.nearest_observation(*topk.top_k_softmax(logits[0], k), size)
            return SemanticObservation.of_kernel(classes, probs, self.num_classes)
        if self.postprocess == "fused":
            if tuple(self.input_size) == (h, w) and k <= 3 and topk.njit is not None:
                if pixels is not None and np.shape(pixels) != (h, w):
                    raise InvalidDataError(f"{self.name}: pixels must be a {h}x{w} mask (the "
                                           f"frame's), got shape {np.shape(pixels)}")
                index = None if pixels is None else np.flatnonzero(pixels)
                classes, probs = topk.top_k_upsampled(logits[0], size, k, index)
                return SemanticObservation.of_kernel(classes, probs, self.num_classes)
            # the network's own final resize (align_corners, as models.layers.resize_to)
            logits = _resized(logits, self.input_size, align_corners=True)
        if tuple(logits.shape[-2:]) != (h, w):
            logits = _resized(logits, (h, w), align_corners=False)
        classes, probs = topk.top_k_softmax(logits[0], k)
        return SemanticObservation.of_kernel(classes, probs, self.num_classes)


def _resized(logits: torch.Tensor, size: tuple[int, int], *, align_corners: bool
             ) -> torch.Tensor:
    """Host ``logits`` (1, C, h, w) resized bilinearly to ``size`` by evsmap's kernel
    (:func:`evsmap.segmenters.resize.bilinear`: the same bits whatever torch's thread count,
    which its own bilinear kernel does not promise)."""
    from evsmap.segmenters.resize import bilinear

    return torch.from_numpy(bilinear(logits[0].numpy(), size, align_corners=align_corners))[None]


def _top_k_on_device(logits: torch.Tensor, size: tuple[int, int], k: int,
                     num_classes: int) -> SemanticObservation:
    """The faithful post-processing on the logits' own device (a GPU): bilinear resize to
    ``size`` where they differ, softmax over the classes, top-``k``; only the top-k (k values
    and classes a pixel) cross to the host. The reference order of :func:`~evsmap.segmenters.
    topk.top_k_softmax` (softmax, then top-k), in float32."""
    with torch.inference_mode():
        x = logits.float()
        if tuple(x.shape[-2:]) != tuple(size):
            x = F.interpolate(x, size=size, mode="bilinear", align_corners=False)
        top_p, top_c = torch.softmax(x[0], dim=0).topk(k, dim=0)
        classes = top_c.permute(1, 2, 0).to(torch.int16).cpu().numpy()
        probs = top_p.permute(1, 2, 0).clamp(0.0, 1.0).cpu().numpy()
    return SemanticObservation.of_kernel(np.ascontiguousarray(classes),
                                         np.ascontiguousarray(probs), num_classes)
