"""3DGNN-R101: the 3D graph neural network of Qi, Liao, Jia, Fidler and Urtasun (ICCV 2017) on a
ResNet-101 unary CNN, designed from the paper (no public code has this configuration: the
authors' release is Caffe with ResNet-50). docs/baselines/3dgnn-r101.md gives every choice and
the sentence or source it serves.

* Unary CNN: a DeepLab-style ResNet-101 (output stride 8, dilated ``layer3``/``layer4``) on the
  RGB image, then a 1x1 convolution with bias and a ReLU to the hidden width (1024): the initial
  hidden state ``h0`` of every node.
* Graph: one node per cell of the 1/8 feature map; its 3D point is the depth at the cell centre
  back-projected with the camera intrinsics (NYUv2's Kinect colour camera, scaled to the input);
  each node is joined to its ``K = 64`` nearest nodes in 3D (itself included).
* Propagation, ``T = 3`` steps: the message of node ``v`` is the mean of ``g(h_u)`` over its
  neighbours, ``g`` a fully connected layer with ReLU; the new state is
  ``h_v = relu(W [h_v, m_v] + b)`` (the MLP update of the paper's vanilla-RNN form).
* Prediction: a fully connected layer on ``[h0, hT]`` per node gives the class logits at 1/8 of
  the input (the segmenter resizes them).

The mean over neighbours is a product with a row-normalised adjacency matrix (``1/K`` at each
neighbour), built from the k-nearest-neighbour indices by a scatter: no ``(N, K, C)`` gather.
With 40 classes the model has 47,828,072 parameters (Table I: 47.3 M, +1.1 %).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from baselines.backbones.resnet import ResNet, resnet101

__all__ = [
    "GraphPropagation",
    "NYUV2_INTRINSICS",
    "ThreeDGNN",
    "back_project",
    "gnn3d_r101",
    "knn_adjacency",
]

#: Hidden width of the graph nodes.
HIDDEN = 1024
#: Neighbours per node and propagation steps.
NEIGHBOURS = 64
STEPS = 3
#: NYUv2's colour camera (fx, fy, cx, cy) at its 640x480 resolution (the toolbox's
#: ``camera_params.m``); scaled to the network's input size.
NYUV2_INTRINSICS = (518.857901, 519.469611, 325.582449, 253.736166)
NYUV2_SIZE = (480, 640)


def back_project(depth: Tensor, size: tuple[int, int], *,
                 intrinsics: tuple[float, float, float, float] = NYUV2_INTRINSICS,
                 intrinsics_size: tuple[int, int] = NYUV2_SIZE) -> Tensor:
    """3D points ``(B, h*w, 3)`` (metres, camera frame) of the centres of an ``h x w`` grid
    over ``depth`` ``(B, 1, H, W)`` (metres; invalid 0 maps to the camera centre).

    The depth is sampled at each cell centre (nearest); ``intrinsics`` (fx, fy, cx, cy) belong
    to an image of ``intrinsics_size`` and are scaled to ``H x W``.
    """
    batch, _, height, width = depth.shape
    h, w = size
    fx, fy, cx, cy = intrinsics
    sy, sx = height / intrinsics_size[0], width / intrinsics_size[1]
    fx, cx, fy, cy = fx * sx, (cx + 0.5) * sx - 0.5, fy * sy, (cy + 0.5) * sy - 0.5
    z = F.interpolate(depth, size=(h, w), mode="nearest").reshape(batch, h * w)
    u = (torch.arange(w, dtype=depth.dtype, device=depth.device) + 0.5) * (width / w) - 0.5
    v = (torch.arange(h, dtype=depth.dtype, device=depth.device) + 0.5) * (height / h) - 0.5
    rx = ((u - cx) / fx).repeat(h)
    ry = ((v - cy) / fy).repeat_interleave(w)
    return torch.stack((rx * z, ry * z, z), dim=-1)


def knn_adjacency(points: Tensor, neighbours: int) -> Tensor:
    """Row-normalised adjacency ``(B, N, N)`` of the ``neighbours`` nearest points of each point
    (itself included; all of them when there are fewer): ``A @ x`` averages ``x`` over each
    point's neighbours."""
    k = min(neighbours, points.shape[1])
    sq = (points * points).sum(-1)
    dist = sq.unsqueeze(2) + sq.unsqueeze(1) - 2.0 * points @ points.transpose(1, 2)
    index = torch.topk(-dist, k, dim=-1).indices
    weights = torch.full(index.shape, 1.0 / k, dtype=points.dtype, device=points.device)
    return torch.zeros_like(dist).scatter(2, index, weights)


class GraphPropagation(nn.Module):
    """``steps`` rounds of ``m = A relu(G h)``, ``h = relu(U [h, m])`` over a fixed graph.

    Args:
        channels: hidden width.
        steps: propagation steps (the unrolled recurrence).
    """

    def __init__(self, *, channels: int, steps: int = STEPS) -> None:
        super().__init__()
        self.message = nn.Linear(channels, channels)
        self.update = nn.Linear(2 * channels, channels)
        self.steps = steps

    def forward(self, h: Tensor, adjacency: Tensor) -> Tensor:
        for _ in range(self.steps):
            m = adjacency @ F.relu(self.message(h))
            h = F.relu(self.update(torch.cat((h, m), dim=-1)))
        return h


class ThreeDGNN(nn.Module):
    """3DGNN on a ResNet unary CNN (see the module notes); ``forward(rgb, depth)`` with depth
    in metres returns logits at 1/8 of the input size.

    Args:
        encoder: the unary ResNet (output stride 8).
        num_classes: classifier outputs.
        hidden: node width.
        neighbours: K of the k-nearest-neighbour graph.
        steps: propagation steps.
    """

    def __init__(self, *, encoder: ResNet, num_classes: int, hidden: int = HIDDEN,
                 neighbours: int = NEIGHBOURS, steps: int = STEPS) -> None:
        super().__init__()
        self.encoder = encoder
        self.embed = nn.Conv2d(encoder.channels[-1], hidden, kernel_size=1, bias=True)
        self.propagation = GraphPropagation(channels=hidden, steps=steps)
        self.classifier = nn.Linear(2 * hidden, num_classes)
        self.neighbours = neighbours

    def forward(self, rgb: Tensor, depth: Tensor) -> Tensor:
        unary = F.relu(self.embed(self.encoder.forward_features(rgb)[-1]))
        batch, channels, h, w = unary.shape
        h0 = unary.flatten(2).transpose(1, 2)  # (B, N, C)
        adjacency = knn_adjacency(back_project(depth, (h, w)), self.neighbours)
        ht = self.propagation(h0, adjacency)
        logits = self.classifier(torch.cat((h0, ht), dim=-1))  # (B, N, classes)
        return logits.transpose(1, 2).reshape(batch, -1, h, w)


def gnn3d_r101(*, num_classes: int) -> ThreeDGNN:
    """3DGNN with a ResNet-101 unary CNN and ``num_classes`` outputs.

    Args:
        num_classes: classifier outputs (40 for NYUv2: 47,828,072 parameters; 37 for SUN
            RGB-D).
    """
    return ThreeDGNN(encoder=resnet101(output_stride=8), num_classes=num_classes)
