"""ONNX Runtime's execution providers: which one runs a session, checked before it is built and
after (ONNX Runtime falls back to the CPU without a word when a GPU provider fails to load).

``cpu`` is in every ONNX Runtime; ``cuda`` and ``tensorrt`` come with the GPU build
(``onnxruntime-gpu``, the ``evsmap[gpu]`` extra) and TensorRT's own libraries. A TensorRT
session runs what TensorRT takes and hands the rest to CUDA, then the CPU (its documented
chain); with ``fp16`` TensorRT builds fp16 engines (``trt_fp16_enable``), cached under
evsmap's cache (``onnx/tensorrt``) so the minutes of an engine build are paid once per graph.
"""

from __future__ import annotations

from typing import Any

from evsmap.devices import DeviceUnavailableError
from evsmap.errors import UnknownNameError

PROVIDERS = {"cpu": "CPUExecutionProvider", "cuda": "CUDAExecutionProvider",
             "tensorrt": "TensorrtExecutionProvider"}
"""``--provider`` names -> ONNX Runtime's."""


def default_provider(device: str) -> str:
    """The provider a device runs ONNX graphs with by default: ``cuda`` on a GPU."""
    return "cuda" if device.startswith("cuda") else "cpu"


def provider_chain(provider: str, *, device_index: int = 0, fp16: bool = False) -> list[Any]:
    """The ``providers`` argument of an ONNX Runtime session for ``provider``: it, then the
    ones ONNX Runtime falls back to for nodes it does not take.

    Raises:
        UnknownNameError: not one of :data:`PROVIDERS`.
        DeviceUnavailableError: this ONNX Runtime lacks it (one line naming the extra).
    """
    import onnxruntime as ort

    if provider not in PROVIDERS:
        raise UnknownNameError(f"unknown ONNX Runtime provider {provider!r} (known: "
                               f"{', '.join(PROVIDERS)})")
    name = PROVIDERS[provider]
    available = ort.get_available_providers()
    if name not in available:
        extra = " and TensorRT's libraries" if provider == "tensorrt" else ""
        raise DeviceUnavailableError(
            f"--provider {provider}: ONNX Runtime {ort.__version__} here has no {name} "
            f"(it has {', '.join(available)}); install the GPU build: pip install -c "
            f"constraints.txt 'evsmap[gpu]' (onnxruntime-gpu){extra}")
    if provider == "cpu":
        return [name]
    cuda = ("CUDAExecutionProvider", {"device_id": device_index,
                                      "cudnn_conv_algo_search": "EXHAUSTIVE"})
    if provider == "cuda":
        return [cuda, "CPUExecutionProvider"]
    from evsmap.cache import cache_dir

    engines = cache_dir("onnx") / "tensorrt"
    engines.mkdir(parents=True, exist_ok=True)
    trt = ("TensorrtExecutionProvider", {"device_id": device_index, "trt_fp16_enable": fp16,
                                         "trt_engine_cache_enable": True,
                                         "trt_engine_cache_path": str(engines)})
    return [trt, cuda, "CPUExecutionProvider"]


def check_used(session: Any, provider: str) -> str:
    """The provider ``session`` runs with (its first), after checking it is the one asked for.

    Raises:
        DeviceUnavailableError: ONNX Runtime fell back (a GPU provider that failed to load:
            missing CUDA, cuDNN or TensorRT libraries).
    """
    used = session.get_providers()[0]
    if used != PROVIDERS[provider]:
        raise DeviceUnavailableError(
            f"--provider {provider}: ONNX Runtime fell back to {used} ({PROVIDERS[provider]} "
            f"did not load: its CUDA, cuDNN or TensorRT libraries are missing or of another "
            f"version; ONNX Runtime's log says which)")
    return used
