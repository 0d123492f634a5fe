"""Helpers for torch modules and their inputs (shared by the measurements and the ONNX export)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence

import torch


def as_inputs(inputs: torch.Tensor | Sequence[torch.Tensor]) -> tuple[torch.Tensor, ...]:
    """``inputs`` as a non-empty tuple of tensors (a single tensor is wrapped)."""
    if isinstance(inputs, torch.Tensor):
        return (inputs,)
    inputs = tuple(inputs)
    if not inputs or not all(isinstance(t, torch.Tensor) for t in inputs):
        raise TypeError("inputs must be a tensor or a non-empty sequence of tensors")
    return inputs


def image_size(inputs: tuple[torch.Tensor, ...]) -> tuple[int, int]:
    """(height, width) of the first input (the last two dimensions)."""
    first = inputs[0]
    if first.dim() < 2:
        raise ValueError(f"first input must be at least 2-D (..., H, W), got {tuple(first.shape)}")
    return int(first.shape[-2]), int(first.shape[-1])


@contextlib.contextmanager
def eval_mode(module: torch.nn.Module) -> Iterator[torch.nn.Module]:
    """Put ``module`` in eval mode for the block, then restore each submodule's mode."""
    modes = [(m, m.training) for m in module.modules()]
    module.eval()
    try:
        yield module
    finally:
        for m, training in modes:
            m.training = training


@contextlib.contextmanager
def torch_threads(threads: int) -> Iterator[int]:
    """Run the block with torch's intra-op threads set to ``threads``, then restore them."""
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield threads
    finally:
        torch.set_num_threads(previous)
