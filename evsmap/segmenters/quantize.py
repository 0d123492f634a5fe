"""Static int8 quantisation (QDQ) of a network's cached fp32 ONNX export, and its cache.

The scheme (:data:`SCHEMES`) is chosen per instruction set by default (``auto``,
:data:`AUTO_SCHEMES`, issue 32), and a model is cached per instruction set.

Serves issue 20 ("int8 inference"): ONNX Runtime static quantisation in QDQ format after
``quant_pre_process``, calibrated with a :class:`~onnxruntime.quantization.CalibrationDataReader`
over frames of the target data, per-channel weights, the nodes that lose accuracy kept in fp32,
the quantised model cached by weights, calibration set and settings.

:func:`quantize_model` does the work: shape inference and ORT's graph optimisation
(``quant_pre_process``), then ``quantize_static`` with the scheme's types (:data:`SCHEMES`),
keeping in fp32 the nodes :func:`rule_exclusions` names (the final classifier and everything
after it, sigmoid gates, softmax) and, with ``auto_exclude=N``, the nodes around the N tensors
whose quantisation noise is largest on the calibration inputs (:func:`rank_tensors`, ORT's
``qdq_loss_debug``). The result is written to the ONNX cache folder under a name that hashes
the fp32 file, the calibration inputs and every setting, beside a JSON sidecar that records
them (:class:`QuantizedModel`). :func:`reestimate_batchnorm` gives an untrained network
activations of realistic scale for measuring int8 agreement without trained weights. Only that
function imports torch.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import re
import shutil
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from evsmap.errors import InvalidDataError, UnknownNameError
from evsmap.fileio import atomic_path

SCHEMES = ("u8s8", "u8s7", "u8u8", "s8s8")
"""The int8 types, activations then weights (activations asymmetric, int8 weights symmetric):

* ``u8s8``: uint8 activations, int8 weights - ONNX Runtime's fast x86 kernels; exact with VNNI
  (``VPDPBUSD`` accumulates in 32 bits), but without VNNI they multiply through ``VPMADDUBSW``,
  whose sum of two u8 x s8 products saturates at 16 bits (255 x 127 x 2 > 32767);
* ``u8s7``: as ``u8s8`` with 7-bit weights (ORT's ``reduce_range``): 255 x 64 x 2 fits in 16
  bits, so the same fast kernels do not saturate, for one bit less of weight resolution;
* ``u8u8``: uint8 weights too (asymmetric): ORT's u8u8 kernels widen to 16 bits before the
  multiply and never saturate;
* ``s8s8``: int8 activations - ORT's default format, the usual choice on ARM. On x86 ONNX
  Runtime's convolution and matmul kernels take uint8 activations (int8 ones are shifted by
  128 first: the session option ``session.qdqisint8allowed`` is off there), so s8s8 saturates
  as u8s8 does; on the test network, whose integer nodes are all convolutions, the outputs are
  identical.

ONNX Runtime's quantisation guide gives the same advice for machines without VNNI: try
``reduce_range`` or u8u8 when u8s8 loses accuracy. :data:`AUTO_SCHEMES` is evsmap's choice."""

AUTO = "auto"
"""The scheme name that means :func:`auto_scheme` for this machine's instruction set."""

AUTO_SCHEMES = {"exact": "u8s8", "saturating": "u8s7"}
"""``auto``: ``u8s8`` where int8 products accumulate exactly
(:data:`evsmap.environment.INT8_EXACT_SETS`: VNNI, AMX, ARM), ``u8s7`` elsewhere (AVX2 or
AVX-512 without VNNI): the accuracy of u8u8 there, on the fast u8s8 kernels. Measured per
scheme and instruction set in docs/int8.md, "Per instruction set"."""


def auto_scheme(instruction_set: str | None = None) -> str:
    """The scheme ``auto`` means on ``instruction_set`` (default this machine's)."""
    from evsmap.environment import int8_exact

    return AUTO_SCHEMES["exact" if int8_exact(instruction_set) else "saturating"]


def resolve_scheme(scheme: str | None, instruction_set: str | None = None) -> tuple[str, str]:
    """``(scheme, chosen_by)``: ``auto`` (or None) becomes :func:`auto_scheme`'s and
    ``chosen_by`` says so (``"auto for avx2"``); a named scheme is kept (``"given"``).

    Raises:
        UnknownNameError: not a scheme of :data:`SCHEMES` nor ``auto``.
    """
    from evsmap.environment import instruction_set as this_isa

    if scheme is None or scheme == AUTO:
        isa = instruction_set or this_isa()
        return auto_scheme(isa), f"auto for {isa}"
    if scheme not in SCHEMES:
        raise UnknownNameError(f"unknown int8 scheme {scheme!r} (known: {AUTO}, "
                               f"{', '.join(SCHEMES)})")
    return scheme, "given"


_SCHEME_TYPES = {"u8s8": ("QUInt8", "QInt8", False), "u8s7": ("QUInt8", "QInt8", True),
                 "u8u8": ("QUInt8", "QUInt8", False), "s8s8": ("QInt8", "QInt8", False)}
"""Activation type, weight type and ``reduce_range`` of each scheme (ORT's ``QuantType``)."""

METHODS = ("minmax", "percentile", "entropy")
"""Calibration methods: ``minmax`` (default; ranges are the observed extremes), ``percentile``
(99.999th percentile of |x|) and ``entropy`` (KL-divergence threshold), the last two from
histograms (slower)."""

RULE_OP_TYPES = ("Sigmoid", "HardSigmoid", "Softmax")
"""Operators kept in fp32 by rule: gates and attention weights in [0, 1], where a few
quantisation steps are a large relative error."""

_COMPUTE_OPS = ("Conv", "ConvTranspose", "Gemm", "MatMul")
SIDECAR_SUFFIX = ".json"


@dataclass(frozen=True)
class Int8Settings:
    """How a network is quantised (every field is part of the cache key).

    Args:
        scheme: one of :data:`SCHEMES` (resolve ``auto`` first: :func:`resolve_scheme`).
        method: calibration method (:data:`METHODS`).
        rules: keep :func:`rule_exclusions`'s nodes in fp32.
        auto_exclude: also keep in fp32 the nodes around this many tensors with the lowest
            quantisation SQNR on the calibration inputs (0: none).
        exclude: further node names (of the pre-processed graph) kept in fp32.
        instruction_set: the instruction set the model is made for and run on (default this
            machine's, :func:`evsmap.environment.instruction_set`): a model quantised for one
            is not reused on another, whose kernels round differently.
    """

    scheme: str = "u8s8"
    method: str = "minmax"
    rules: bool = True
    auto_exclude: int = 0
    exclude: tuple[str, ...] = ()
    instruction_set: str = ""

    def __post_init__(self) -> None:
        if self.scheme not in SCHEMES:
            raise UnknownNameError(f"unknown int8 scheme {self.scheme!r} (known: "
                                   f"{', '.join(SCHEMES)})")
        if self.method not in METHODS:
            raise UnknownNameError(f"unknown calibration method {self.method!r} (known: "
                                   f"{', '.join(METHODS)})")
        if self.auto_exclude < 0:
            raise InvalidDataError(f"auto_exclude must be >= 0, got {self.auto_exclude}")
        object.__setattr__(self, "exclude", tuple(self.exclude))
        if not self.instruction_set:
            from evsmap.environment import instruction_set

            object.__setattr__(self, "instruction_set", instruction_set())


@dataclass(frozen=True)
class QuantizedModel:
    """An int8 model in the cache and how it was made (its JSON sidecar).

    Attributes:
        path: the quantised ONNX file.
        fp32_digest: sha256 of the fp32 ONNX file it was made from.
        calibration_digest: :func:`inputs_digest` of the calibration inputs.
        calibration_frames: how many calibration inputs there were.
        calibration_source: what they were (e.g. ``"synthetic frames 0, 4, 8"``), free text.
        settings: the :class:`Int8Settings` as a dict.
        excluded: node names kept in fp32 (rules, automatic choice and ``exclude``).
        auto_ranking: with ``auto_exclude``: ``[tensor, SQNR dB]`` of the tensors chosen,
            worst first.
        onnxruntime: the ORT version that quantised it.
        cached: whether this call found it in the cache (not stored in the sidecar).
    """

    path: Path
    fp32_digest: str
    calibration_digest: str
    calibration_frames: int
    calibration_source: str
    settings: dict[str, Any]
    excluded: tuple[str, ...]
    auto_ranking: list[list[Any]] = field(default_factory=list)
    onnxruntime: str = ""
    cached: bool = False

    @property
    def instruction_set(self) -> str:
        """The instruction set it was quantised for (:attr:`Int8Settings.instruction_set`)."""
        return str(self.settings.get("instruction_set", ""))

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["path"] = str(self.path)
        d["excluded"] = list(self.excluded)
        return d

    @classmethod
    def from_sidecar(cls, path: Path) -> QuantizedModel:
        record = json.loads(path.with_suffix(SIDECAR_SUFFIX).read_text())
        record.update(path=path, excluded=tuple(record["excluded"]), cached=True)
        return cls(**record)


def calibration_reader(inputs: Sequence[Mapping[str, np.ndarray]], *,
                       keep: Sequence[str] | None = None) -> Any:
    """A :class:`~onnxruntime.quantization.CalibrationDataReader` over prepared inputs: each
    item maps input names to float32 arrays (batch 1), fed in order; ``rewind()`` starts over.
    Names not in ``keep`` (inputs the graph dropped, e.g. an unused depth) are left out of the
    feed. (The class is made here so that importing this module does not import ORT.)"""
    from onnxruntime.quantization import CalibrationDataReader

    class InputsReader(CalibrationDataReader):
        def __init__(self) -> None:
            self._items = [{k: np.ascontiguousarray(v, dtype=np.float32)
                            for k, v in item.items() if keep is None or k in keep}
                           for item in inputs]
            self._at = 0

        def get_next(self) -> dict[str, np.ndarray] | None:
            if self._at >= len(self._items):
                return None
            self._at += 1
            return self._items[self._at - 1]

        def rewind(self) -> None:
            self._at = 0

    return InputsReader()


def evenly_spaced(total: int, count: int) -> list[int]:
    """``count`` indices spread evenly over ``range(total)`` (all of them when ``count >=
    total``): the frames of a sequence an int8 model is calibrated on."""
    if total < 1 or count < 1:
        raise InvalidDataError(f"need at least one frame to calibrate on (sequence of {total}, "
                               f"{count} asked)")
    if count >= total:
        return list(range(total))
    return sorted({int(round(i * (total - 1) / (count - 1))) for i in range(count)}) \
        if count > 1 else [total // 2]


def inputs_digest(inputs: Sequence[Mapping[str, np.ndarray]]) -> str:
    """sha256 over the names, shapes, dtypes and bytes of every calibration input, in order."""
    h = hashlib.sha256()
    for item in inputs:
        for name in sorted(item):
            a = np.ascontiguousarray(item[name], dtype=np.float32)
            h.update(f"{name}{a.shape}".encode())
            h.update(a.tobytes())
        h.update(b"\0")
    return h.hexdigest()


def file_digest(path: str | os.PathLike[str]) -> str:
    """sha256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def rule_exclusions(model: Any) -> list[str]:
    """Names of the nodes of ``model`` (an ``onnx.ModelProto``) kept in fp32 by rule: every
    :data:`RULE_OP_TYPES` node, and the tail of the graph - each graph output's producers back
    to and including the first convolution/matmul met (the final classifier and the logits'
    upsampling)."""
    producer = {out: node for node in model.graph.node for out in node.output}
    names = [n.name for n in model.graph.node if n.op_type in RULE_OP_TYPES]
    seen: set[str] = set()
    stack = [o.name for o in model.graph.output]
    while stack:
        node = producer.get(stack.pop())
        if node is None or node.name in seen:
            continue
        seen.add(node.name)
        names.append(node.name)
        if node.op_type not in _COMPUTE_OPS:
            stack.extend(node.input)
    return list(dict.fromkeys(names))


def _name_nodes(model: Any) -> None:
    """Give every unnamed node a unique name (exclusion works by node name)."""
    taken = {n.name for n in model.graph.node if n.name}
    for i, node in enumerate(model.graph.node):
        if not node.name:
            name = f"{node.op_type}_{i}"
            while name in taken:
                name += "_"
            node.name = name
            taken.add(name)


def _quantize(pre: Path, out: Path, reader: Any, settings: Int8Settings,
              exclude: Sequence[str]) -> None:
    from onnxruntime.quantization import (
        CalibrationMethod,
        QuantFormat,
        QuantType,
        quantize_static,
    )

    activation, weight, reduce_range = _SCHEME_TYPES[settings.scheme]
    method = {"minmax": CalibrationMethod.MinMax, "percentile": CalibrationMethod.Percentile,
              "entropy": CalibrationMethod.Entropy}[settings.method]
    reader.rewind()
    quantize_static(
        str(pre), str(out), reader, quant_format=QuantFormat.QDQ, per_channel=True,
        reduce_range=reduce_range, activation_type=getattr(QuantType, activation),
        weight_type=getattr(QuantType, weight), nodes_to_exclude=list(exclude) or None,
        calibrate_method=method,
        extra_options={"ActivationSymmetric": False, "WeightSymmetric": weight == "QInt8"})


def rank_tensors(*, fp32_path: str | os.PathLike[str], qdq_path: str | os.PathLike[str],
                 reader: Any, workdir: str | os.PathLike[str]) -> list[tuple[str, float]]:
    """Activation tensors of a QDQ model ranked by their quantisation SQNR (dB, lowest first).

    Uses ORT's ``qdq_loss_debug``: both models are augmented to output their intermediate
    tensors (``modify_model_output_intermediate_tensors``), run one calibration input at a time
    (``collect_activations``), matched (``create_activation_matching``) and scored
    (``compute_activation_error``); a tensor's score is the mean over inputs of ``qdq_err``,
    the SQNR of the tensor against its quantised-dequantised self in the QDQ model (the noise
    quantising this tensor adds, not what it inherits; a Relu output is compared after the
    clamp, which QDQ folds into the quantisation). Tensors that are all zero (a residual scale
    initialised to 0) score 0 dB and are left out.

    Args:
        fp32_path: the pre-processed fp32 model.
        qdq_path: its QDQ quantisation.
        reader: a :func:`calibration_reader` of the calibration inputs.
        workdir: folder for the two augmented models.
    """
    import onnx
    from onnxruntime.quantization.qdq_loss_debug import (
        collect_activations,
        compute_activation_error,
        create_activation_matching,
        modify_model_output_intermediate_tensors,
    )

    relu_outputs = {o for n in onnx.load(str(fp32_path)).graph.node if n.op_type == "Relu"
                    for o in n.output}
    workdir = Path(workdir)
    aug_fp32, aug_qdq = workdir / "aug_fp32.onnx", workdir / "aug_qdq.onnx"
    modify_model_output_intermediate_tensors(str(fp32_path), str(aug_fp32))
    modify_model_output_intermediate_tensors(str(qdq_path), str(aug_qdq))
    reader.rewind()
    items = list(iter(reader.get_next, None))
    scores: dict[str, list[float]] = {}
    zeros: set[str] = set()
    for item in items:
        one = calibration_reader([item])
        float_acts = collect_activations(str(aug_fp32), one)
        one.rewind()
        qdq_acts = collect_activations(str(aug_qdq), one)
        matching = create_activation_matching(qdq_acts, float_acts)
        for name in relu_outputs.intersection(matching):
            # QDQ drops a Relu after a quantised node: the tensor before its QuantizeLinear is
            # then the Relu's input, and the clamp is not quantisation noise
            matching[name]["pre_qdq"] = [np.maximum(a, 0) for a in matching[name]["pre_qdq"]]
        errors = compute_activation_error(matching)
        zeros.update(name for name, m in matching.items()
                     if not any(np.any(a) for a in m["pre_qdq"]))
        for name, err in errors.items():
            scores.setdefault(name, []).append(float(err["qdq_err"]))
    ranked = [(name, float(np.mean(v))) for name, v in scores.items() if name not in zeros]
    return sorted(ranked, key=lambda pair: pair[1])


def _with_consumers(model: Any, names: Sequence[str]) -> list[str]:
    """``names`` followed by every node that reads one of their outputs: with its consumers
    excluded too, an excluded node's output is not quantised (else ONNX Runtime would fuse the
    node, between a DequantizeLinear and a QuantizeLinear, into an integer kernel)."""
    wanted = set(names)
    outputs = {o for n in model.graph.node if n.name in wanted for o in n.output}
    return list(dict.fromkeys([*names, *(n.name for n in model.graph.node
                                         if outputs.intersection(n.input))]))


def _nodes_around(model: Any, tensors: Sequence[str]) -> list[str]:
    """The producer and every consumer of each tensor: excluded together, the tensor stays
    float."""
    wanted = set(tensors)
    return [n.name for n in model.graph.node
            if wanted.intersection(n.output) or wanted.intersection(n.input)]


def cache_path(*, stem: str, fp32_digest: str, calibration_digest: str,
               settings: Int8Settings, cache_dir: str | os.PathLike[str]) -> Path:
    """Where the int8 model of these inputs lives: ``<stem>-int8-<scheme>-<instruction
    set>-<hash>.onnx``, the hash over the fp32 file's digest, the calibration digest, the
    settings (the instruction set among them) and the ORT version."""
    h = hashlib.sha256()
    for part in (fp32_digest, calibration_digest,
                 json.dumps(asdict(settings), sort_keys=True), metadata.version("onnxruntime")):
        h.update(part.encode())
        h.update(b"\0")
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", stem).strip("._") or "model"
    isa = re.sub(r"[^A-Za-z0-9.-]+", "_", settings.instruction_set)
    return Path(cache_dir) / (f"{stem[:48]}-int8-{settings.scheme}-{isa}-"
                              f"{h.hexdigest()[:20]}.onnx")


def quantize_model(
    *,
    fp32_path: str | os.PathLike[str],
    calibration: Sequence[Mapping[str, np.ndarray]],
    settings: Int8Settings | None = None,
    cache_dir: str | os.PathLike[str] | None = None,
    stem: str | None = None,
    source: str = "",
) -> QuantizedModel:
    """The int8 QDQ model of an fp32 ONNX file, quantised only when not already cached.

    Args:
        fp32_path: the fp32 model (e.g. :func:`evsmap.models.onnx_export.cached_onnx`'s).
        calibration: calibration inputs, each a mapping of input name to a float32 array (batch
            1); inputs the graph does not read are ignored.
        settings: scheme, method and fp32 nodes (default :class:`Int8Settings`).
        cache_dir: where to keep it (default: the ONNX export cache folder).
        stem: readable start of the file name (default: the fp32 file's stem).
        source: what the calibration inputs are, for the sidecar.

    Raises:
        InvalidDataError: no calibration input.
    """
    import onnx
    from onnxruntime.quantization.shape_inference import quant_pre_process

    settings = settings or Int8Settings()
    if not calibration:
        raise InvalidDataError("int8 quantisation needs at least one calibration input")
    fp32_path = Path(fp32_path)
    if cache_dir is None:
        from evsmap.models.onnx_export import default_cache_dir

        cache_dir = default_cache_dir()
    fp32_digest = file_digest(fp32_path)
    graph_inputs = [i.name for i in onnx.load(str(fp32_path), load_external_data=False)
                    .graph.input]
    cal_digest = inputs_digest([{k: v for k, v in item.items() if k in graph_inputs}
                                for item in calibration])
    path = cache_path(stem=stem or fp32_path.stem, fp32_digest=fp32_digest,
                      calibration_digest=cal_digest, settings=settings, cache_dir=cache_dir)
    if path.is_file() and path.with_suffix(SIDECAR_SUFFIX).is_file():
        return QuantizedModel.from_sidecar(path)
    Path(cache_dir).mkdir(parents=True, exist_ok=True)
    reader = calibration_reader(calibration, keep=graph_inputs)
    with tempfile.TemporaryDirectory(prefix="evsmap-int8-") as tmp, _quiet():
        work = Path(tmp)
        pre = work / "pre.onnx"
        quant_pre_process(str(fp32_path), str(pre))
        model = onnx.load(str(pre))
        _name_nodes(model)
        onnx.save(model, str(pre))
        core = (rule_exclusions(model) if settings.rules else []) + list(settings.exclude)
        excluded = _with_consumers(model, core)
        ranking: list[list[Any]] = []
        first = work / "q.onnx"
        _quantize(pre, first, reader, settings, excluded)
        if settings.auto_exclude:
            ranked = rank_tensors(fp32_path=pre, qdq_path=first, reader=reader, workdir=work)
            worst = ranked[:settings.auto_exclude]
            ranking = [[name, round(db, 2)] for name, db in worst]
            excluded = list(dict.fromkeys(
                excluded + _nodes_around(model, [name for name, _ in worst])))
            _quantize(pre, first, reader, settings, excluded)
        record = QuantizedModel(
            path=path, fp32_digest=fp32_digest, calibration_digest=cal_digest,
            calibration_frames=len(calibration), calibration_source=source,
            settings=asdict(settings), excluded=tuple(excluded), auto_ranking=ranking,
            onnxruntime=metadata.version("onnxruntime"))
        sidecar = record.as_dict()
        for key in ("path", "cached"):
            sidecar.pop(key)
        with atomic_path(path.with_suffix(SIDECAR_SUFFIX), suffix=".json") as tmp_json:
            tmp_json.write_text(json.dumps(sidecar, indent=2) + "\n")
        with atomic_path(path, suffix=".onnx") as tmp_onnx:
            shutil.copyfile(first, tmp_onnx)  # the temporary folder may be another filesystem
    return record


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """Silence the quantiser's logging warnings (one per rank-1 weight it cannot quantise per
    channel, and quantised per tensor instead)."""
    logging.disable(logging.WARNING)
    try:
        yield
    finally:
        logging.disable(logging.NOTSET)


def float_nodes(path: str | os.PathLike[str], names: Sequence[str]) -> dict[str, bool]:
    """For each node name, whether the saved model at ``path`` runs it in fp32: the node is
    there, none of its outputs goes to a ``QuantizeLinear`` and none of its inputs is a
    quantised weight (an initializer through ``DequantizeLinear``). ONNX Runtime fuses a node
    into an integer kernel only when it reads DequantizeLinear outputs and writes into a
    QuantizeLinear, so such a node computes in float."""
    import onnx

    model = onnx.load(str(path), load_external_data=False)
    constants = {t.name for t in model.graph.initializer}
    weights = {o for n in model.graph.node
               if n.op_type == "DequantizeLinear" and n.input[0] in constants for o in n.output}
    quantized = {n.input[0] for n in model.graph.node if n.op_type == "QuantizeLinear"}
    nodes = {n.name: n for n in model.graph.node}
    return {name: name in nodes and not quantized.intersection(nodes[name].output)
            and not weights.intersection(nodes[name].input) for name in names}


def reestimate_batchnorm(module: Any, inputs: Sequence[Sequence[Any]]) -> None:
    """Replace the running statistics of every BatchNorm of ``module`` by those of ``inputs``
    (each a tuple of batch-1 tensors, at least two; run in batches of up to 4, a cumulative
    average over them), leaving weights as they are; the module is left in eval mode.

    A seeded untrained network keeps BatchNorm's initial statistics (mean 0, variance 1), so
    its activations drift in scale through the layers and its logits are dominated by biases
    (one class everywhere): int8 agreement measured on it says nothing. With statistics from
    real frames, the activations have the scale a trained network's have.
    """
    import torch

    norms = [m for m in module.modules() if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]
    saved = [m.momentum for m in norms]
    for m in norms:
        m.reset_running_stats()
        m.momentum = None
    module.train()
    try:
        items = [tuple(item) for item in inputs]
        with torch.no_grad():  # batches of 2-4: a BatchNorm after global pooling needs 2
            for start in range(0, len(items), 4):
                chunk = items[start:start + 4]
                if len(chunk) == 1 and start:
                    chunk = items[start - 1:start + 1]
                module(*(torch.cat(parts) for parts in zip(*chunk, strict=True)))
    finally:
        for m, momentum in zip(norms, saved, strict=True):
            m.momentum = momentum
        module.eval()


def top1_agreement(reference: Any, other: Any, frames: Sequence[Any]) -> float:
    """The share of pixels of ``frames`` where ``other``'s top class is ``reference``'s (two
    segmenters with the same preprocessing, e.g. a network in fp32 and in int8), from the raw
    logits of each; ``nan`` without frames."""
    same = total = 0
    for frame in frames:
        inputs = reference.preprocess(frame)
        a = reference.logits(inputs).argmax(1)
        b = other.logits(inputs).argmax(1)
        same += int((a == b).sum())
        total += int(a.numel())
    return same / total if total else float("nan")
