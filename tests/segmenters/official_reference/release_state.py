"""Seeded official-layout tensors shared by ``make_reference.py`` (which runs the official code
on them) and ``test_official_predictions.py`` (which runs ``evsmap predict`` on them).

Every tensor is drawn from one generator in the sorted order of the official keys, with a scale
fit to its role, so the values depend only on the key set and the seed - not on either code's
initialisation order:

* convolution and linear weights: normal, std ``1 / sqrt(fan_in)`` (activations keep their scale
  through the 34 or 70 layers);
* BatchNorm weights ``1 + 0.1 N``, biases and running means ``0.1 N``, running variances
  ``0.5 + |0.5 N|``; other biases ``0.05 N``; integer tensors (``num_batches_tracked``) 0.
"""

from __future__ import annotations

import math

import torch

SEED = 20261122


def _fan_in(shape: torch.Size) -> int:
    return max(1, math.prod(shape[1:]))


def release_tensors(shapes: dict[str, tuple[torch.Size, torch.dtype]],
                    seed: int = SEED) -> dict[str, torch.Tensor]:
    """``{official key: tensor}`` for ``{official key: (shape, dtype)}``."""
    gen = torch.Generator().manual_seed(seed)
    out: dict[str, torch.Tensor] = {}
    for key in sorted(shapes):
        shape, dtype = shapes[key]
        shape = torch.Size(shape)
        if not dtype.is_floating_point:
            out[key] = torch.zeros(shape, dtype=dtype)
            continue
        noise = torch.randn(shape, generator=gen, dtype=torch.float32)
        leaf = key.rpartition(".")[2]
        if leaf == "running_var":
            value = 0.5 + (0.5 * noise).abs()
        elif leaf == "running_mean":
            value = 0.1 * noise
        elif leaf == "weight" and len(shape) >= 2:
            value = noise / math.sqrt(_fan_in(shape))
        elif leaf == "weight":  # a normalisation layer's scale
            value = 1.0 + 0.1 * noise
        else:
            value = (0.1 if leaf == "bias" and len(shape) == 1 else 0.05) * noise
        out[key] = value.to(dtype)
    return out


def shapes_of(state: dict[str, torch.Tensor]) -> dict[str, tuple[torch.Size, torch.dtype]]:
    return {key: (value.shape, value.dtype) for key, value in state.items()}
