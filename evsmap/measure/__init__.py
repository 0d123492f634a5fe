"""Measurements of segmentation networks: parameters, FLOPs (fvcore), ONNX export and speed.

Every function returns a plain record (a dataclass with ``as_dict()``); formatting is the
command line's job (``evsmap complexity``, ``evsmap speed``).
"""

from __future__ import annotations

from evsmap.measure.complexity import ComplexityRecord, measure_complexity
from evsmap.measure.speed import SpeedRecord, measure_speed, roofline_gmacs
from evsmap.measure.speed_backends import BACKENDS
from evsmap.models.onnx_export import OnnxExportError, cached_onnx, export_onnx

__all__ = [
    "BACKENDS",
    "ComplexityRecord",
    "OnnxExportError",
    "SpeedRecord",
    "cached_onnx",
    "export_onnx",
    "measure_complexity",
    "measure_speed",
    "roofline_gmacs",
]
