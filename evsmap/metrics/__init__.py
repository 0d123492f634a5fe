"""Scores: 2D segmentation (a dataset-level confusion matrix) and the 3D quality of a map
against voxel ground truth."""

from evsmap.metrics.mapping import MapQuality, evaluate_map, nearest_within, neighbour_offsets
from evsmap.metrics.segmentation import ConfusionMatrix, SegmentationResult

__all__ = ["ConfusionMatrix", "MapQuality", "SegmentationResult", "evaluate_map",
           "nearest_within", "neighbour_offsets"]
