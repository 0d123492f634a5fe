"""Training losses of EVSMaP (paper section III-A-5, eqs. 1-3).

* :class:`DiceLoss` - eq. 2, the squared-denominator (V-Net style) Dice loss on softmax
  probabilities, one term per class, averaged over classes.
* :class:`SoftCrossEntropyLoss` - eq. 3, cross-entropy against a one-hot target that can be
  label-smoothed.
* :class:`HybridLoss` - eq. 1, ``alpha * Dice + beta * SCE`` (``alpha = beta = 1`` in the paper).
* :class:`MultiScaleLoss` - deep ("multi-scale") supervision: any of the above applied to every
  head of a network that returns several logit maps, each against the label map resized with
  :func:`downsample_labels` to that head's size, summed with optional per-head weights.

Conventions shared by all losses:

* Inputs are logits ``(B, C, H, W)`` (floating point) and labels ``(B, H, W)`` ``int64`` holding
  class ids in ``[0, C)`` or :data:`evsmap.data.VOID` (255). Anything else raises
  :class:`ValueError`. When ``C > 255`` the value 255 still means void.
* Void pixels are ignored: they contribute nothing to any sum and do not count as pixels. Their
  logits are replaced by zeros before the softmax, so they get an exactly zero gradient even if
  they are not finite. A batch whose labels are all void has loss 0 and a zero gradient.
* Sums run over every non-void pixel of the whole batch (``i = 1..N`` in the paper), i.e. the
  Dice terms are batch-level, not averaged per image.
* Probabilities are computed in at least float32 (half-precision logits are upcast).

Classes absent from the batch's non-void ground truth are left out of the Dice average (the
mean runs over the classes present): with ``y_c = 0`` the numerator of eq. 2 is zero, so an absent
class's term is the constant 1 with no gradient, and keeping it would only rescale the loss by an
amount that depends on how many classes the batch happens to lack. Absent classes are still
pushed down, through the softmax, by the terms of the present ones (and by the cross-entropy).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from evsmap.data import VOID

__all__ = [
    "DiceLoss",
    "HybridLoss",
    "MultiScaleLoss",
    "SoftCrossEntropyLoss",
    "downsample_labels",
]


def _check_inputs(logits: torch.Tensor, labels: torch.Tensor) -> None:
    """Raise :class:`ValueError` unless ``logits``/``labels`` follow the conventions above."""
    if not isinstance(logits, torch.Tensor) or not isinstance(labels, torch.Tensor):
        raise ValueError(
            f"logits and labels must be torch tensors, got {type(logits).__name__} and "
            f"{type(labels).__name__}"
        )
    if logits.ndim != 4:
        raise ValueError(f"logits must have shape (B, C, H, W), got {tuple(logits.shape)}")
    if not logits.is_floating_point():
        raise ValueError(f"logits must be a floating-point tensor, got {logits.dtype}")
    if logits.shape[1] < 1:
        raise ValueError(f"logits must have at least one class channel, got {tuple(logits.shape)}")
    if labels.dtype != torch.int64:
        raise ValueError(f"labels must be int64 (torch.long), got {labels.dtype}")
    b, c, h, w = logits.shape
    if tuple(labels.shape) != (b, h, w):
        raise ValueError(
            f"labels must have shape (B, H, W) = {(b, h, w)} to match logits "
            f"{tuple(logits.shape)}, got {tuple(labels.shape)}"
        )
    bad = (labels != VOID) & ((labels < 0) | (labels >= c))
    if bool(bad.any()):
        value = int(labels[bad][0])
        raise ValueError(
            f"labels must be class ids in [0, {c}) or void ({VOID}), found {value}"
        )


def _prepare(logits: torch.Tensor, labels: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor,
                                                                   torch.Tensor]:
    """Validated float logits with void pixels zeroed, the void-free labels and the valid mask.

    Returns ``(logits, labels, valid)`` with shapes ``(B, C, H, W)``, ``(B, H, W)`` (void replaced
    by class 0) and ``(B, H, W)`` bool.
    """
    _check_inputs(logits, labels)
    if logits.dtype not in (torch.float32, torch.float64):
        logits = logits.float()
    valid = labels != VOID
    logits = torch.where(valid[:, None], logits, torch.zeros((), dtype=logits.dtype,
                                                             device=logits.device))
    labels = torch.where(valid, labels, torch.zeros((), dtype=labels.dtype, device=labels.device))
    return logits, labels, valid


def _dice_terms(probs: torch.Tensor, labels: torch.Tensor, valid: torch.Tensor, *,
                smooth: float, eps: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Eq. 2's per-class terms from softmax ``probs`` ``(B, C, H, W)``, void-free ``labels`` and
    the ``valid`` mask, without a one-hot tensor: ``sum_i p_ci y_ci`` is the probability of each
    pixel's own class added into its class's slot, and ``sum_i y_ci^2`` the pixel count of each
    class."""
    num_classes = probs.shape[1]
    mask = valid.to(probs.dtype)
    own = probs.gather(1, labels[:, None])[:, 0] * mask
    flat = labels.reshape(-1)
    zeros = torch.zeros(num_classes, dtype=probs.dtype, device=probs.device)
    intersection = zeros.index_add(0, flat, own.reshape(-1))
    support = zeros.index_add(0, flat, mask.reshape(-1))
    squares = (probs * probs * mask[:, None]).sum((0, 2, 3))
    denominator = squares + support + smooth
    terms = 1.0 - (2.0 * intersection + smooth) / denominator.clamp_min(eps)
    return terms, support > 0


def _dice_mean(terms: torch.Tensor, present: torch.Tensor) -> torch.Tensor:
    """The mean of the present classes' terms (0 when none is present)."""
    weights = present.to(terms.dtype)
    return (terms * weights).sum() / weights.sum().clamp_min(1.0)


def _soft_cross_entropy(log_probs: torch.Tensor, labels: torch.Tensor, valid: torch.Tensor,
                        smooth_factor: float) -> torch.Tensor:
    """Eq. 3 from log-probabilities: the mean over valid pixels of the label-smoothed NLL."""
    nll = -log_probs.gather(1, labels[:, None])[:, 0]
    if smooth_factor > 0.0:
        nll = (1.0 - smooth_factor) * nll + smooth_factor * (-log_probs.mean(dim=1))
    mask = valid.to(nll.dtype)
    return (nll * mask).sum() / mask.sum().clamp_min(1.0)


def _describe(value: object) -> object:
    """A tensor's shape, or the type name of anything else, for error messages."""
    return tuple(value.shape) if isinstance(value, torch.Tensor) else type(value).__name__


def _check_number(name: str, value: object, *, low: float, low_inclusive: bool = True,
                  high: float = math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    value = float(value)
    ok_low = value >= low if low_inclusive else value > low
    if not (math.isfinite(value) and ok_low and value < high):
        bound = ("[" if low_inclusive else "(") + f"{low:g}, " + (
            f"{high:g})" if math.isfinite(high) else "inf)")
        raise ValueError(f"{name} must be a finite number in {bound}, got {value!r}")
    return value


class DiceLoss(nn.Module):
    """Eq. 2: ``mean_c [1 - 2 sum_i y_ci p_ci / (sum_i p_ci^2 + sum_i y_ci^2)]``.

    ``p`` are the softmax probabilities, ``y`` the one-hot ground truth, ``i`` runs over the
    non-void pixels of the whole batch and the mean over the classes present in the batch's
    non-void ground truth (0 when there are none). With the defaults the value is exactly eq. 2.

    Args:
        smooth: Laplace smoothing added to both numerator and denominator of every class term
            (``1 - (2 I + smooth) / (D + smooth)``); 0 gives eq. 2 unchanged.
        eps: lower bound on the (smoothed) denominator, a guard against division by zero only. A
            present class has ``sum_i y_ci^2 >= 1``, so it never changes a present class's term.
    """

    def __init__(self, *, smooth: float = 0.0, eps: float = 1e-7) -> None:
        super().__init__()
        self.smooth = _check_number("smooth", smooth, low=0.0)
        self.eps = _check_number("eps", eps, low=0.0, low_inclusive=False)

    def per_class(self, logits: torch.Tensor, labels: torch.Tensor) -> tuple[torch.Tensor,
                                                                             torch.Tensor]:
        """Per-class Dice terms ``(C,)`` and whether each class is present ``(C,)`` bool."""
        logits, labels, valid = _prepare(logits, labels)
        return _dice_terms(torch.softmax(logits, dim=1), labels, valid, smooth=self.smooth,
                           eps=self.eps)

    def forward(self, logits: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
        return _dice_mean(*self.per_class(logits, labels))


class SoftCrossEntropyLoss(nn.Module):
    """Eq. 3: ``-1/N sum_i sum_c q_ic log p_ic`` over the ``N`` non-void pixels of the batch.

    ``q = (1 - smooth_factor) * y + smooth_factor / C`` with ``y`` one-hot (the label smoothing of
    ``torch.nn.functional.cross_entropy``); ``smooth_factor = 0`` gives plain cross-entropy. The
    loss is 0 when ``N = 0``.

    Args:
        smooth_factor: label-smoothing amount in ``[0, 1)``.
    """

    def __init__(self, *, smooth_factor: float = 0.0) -> None:
        super().__init__()
        self.smooth_factor = _check_number("smooth_factor", smooth_factor, low=0.0, high=1.0)

    def forward(self, logits: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
        logits, labels, valid = _prepare(logits, labels)
        return _soft_cross_entropy(torch.log_softmax(logits, dim=1), labels, valid,
                                   self.smooth_factor)


class HybridLoss(nn.Module):
    """Eq. 1: ``alpha * DiceLoss + beta * SoftCrossEntropyLoss``.

    Args:
        alpha: weight of the Dice term (1 in the paper).
        beta: weight of the soft cross-entropy term (1 in the paper).
        smooth_factor: label smoothing of the cross-entropy, see :class:`SoftCrossEntropyLoss`.
        dice_smooth: ``smooth`` of :class:`DiceLoss`.
        dice_eps: ``eps`` of :class:`DiceLoss`.
    """

    def __init__(self, *, alpha: float = 1.0, beta: float = 1.0, smooth_factor: float = 0.0,
                 dice_smooth: float = 0.0, dice_eps: float = 1e-7) -> None:
        super().__init__()
        self.alpha = _check_number("alpha", alpha, low=0.0)
        self.beta = _check_number("beta", beta, low=0.0)
        self.dice = DiceLoss(smooth=dice_smooth, eps=dice_eps)
        self.sce = SoftCrossEntropyLoss(smooth_factor=smooth_factor)

    def forward(self, logits: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
        # one validation and one log-softmax serve both terms (the same values as calling
        # self.dice and self.sce, up to float rounding, at about a third of the cost)
        logits, labels, valid = _prepare(logits, labels)
        log_probs = torch.log_softmax(logits, dim=1)
        dice = _dice_mean(*_dice_terms(log_probs.exp(), labels, valid, smooth=self.dice.smooth,
                                       eps=self.dice.eps))
        sce = _soft_cross_entropy(log_probs, labels, valid, self.sce.smooth_factor)
        return self.alpha * dice + self.beta * sce


def downsample_labels(labels: torch.Tensor, size: Sequence[int]) -> torch.Tensor:
    """Nearest-neighbour resize of an integer label map ``(B, H, W)`` to ``size = (h, w)``.

    Output pixel ``(y, x)`` takes input pixel ``(floor(y H / h), floor(x W / w))`` (PyTorch's
    ``"nearest"``), so at a factor of 2 it is the top-left pixel of each 2x2 block - the centre of
    a stride-2 convolution's window - and no value is ever blended: void stays void. The result is
    ``int64``; ``labels`` is returned unchanged when it already has that size.
    """
    if not isinstance(labels, torch.Tensor) or labels.ndim != 3:
        raise ValueError(f"labels must be a (B, H, W) tensor, got {_describe(labels)}")
    if labels.dtype != torch.int64:
        raise ValueError(f"labels must be int64 (torch.long), got {labels.dtype}")
    size = tuple(int(s) for s in size)
    if len(size) != 2 or min(size) < 1:
        raise ValueError(f"size must be two positive integers (h, w), got {size}")
    if tuple(labels.shape[-2:]) == size:
        return labels
    # Float32 holds every integer up to 2**24 exactly, far beyond any class id or VOID.
    resized = F.interpolate(labels[:, None].float(), size=size, mode="nearest")
    return resized[:, 0].round().long()


class MultiScaleLoss(nn.Module):
    """Deep supervision: ``sum_k w_k * loss(outputs[k], downsample_labels(labels, size_k))``.

    ``outputs`` is what the network returns in training mode: a tuple or list of logit maps (the
    main output at full label resolution first, then the side outputs at lower resolutions) or a
    single tensor, which counts as one head. The first head must have the labels' spatial size
    (a mismatch there is a bug, not a scale); every other head is compared with the label map
    resized by nearest neighbour to its own spatial size.

    Args:
        loss: the per-head loss, called as ``loss(logits, labels)`` (e.g. :class:`HybridLoss`).
        weights: one non-negative weight per head; ``None`` weights every head 1. When given, the
            number of heads must match.
    """

    def __init__(self, *, loss: nn.Module, weights: Sequence[float] | None = None) -> None:
        super().__init__()
        if not callable(loss):
            raise ValueError(f"loss must be callable, got {type(loss).__name__}")
        self.loss = loss
        if weights is not None:
            if isinstance(weights, (str, bytes)) or not isinstance(weights, Sequence):
                raise ValueError(f"weights must be a sequence of numbers, got {weights!r}")
            weights = tuple(
                _check_number(f"weights[{k}]", w, low=0.0) for k, w in enumerate(weights)
            )
            if not weights:
                raise ValueError("weights must not be empty")
        self.weights: tuple[float, ...] | None = weights

    def forward(self, outputs: torch.Tensor | Sequence[torch.Tensor],
                labels: torch.Tensor) -> torch.Tensor:
        heads = [outputs] if isinstance(outputs, torch.Tensor) else list(outputs)
        if not heads:
            raise ValueError("outputs must hold at least one logit map")
        if self.weights is not None and len(self.weights) != len(heads):
            raise ValueError(f"got {len(heads)} output heads but {len(self.weights)} weights")
        if not isinstance(labels, torch.Tensor) or labels.ndim != 3:
            raise ValueError(f"labels must be a (B, H, W) tensor, got {_describe(labels)}")
        weights = self.weights or (1.0,) * len(heads)
        total: torch.Tensor | None = None
        for k, (head, weight) in enumerate(zip(heads, weights, strict=True)):
            if not isinstance(head, torch.Tensor) or head.ndim != 4:
                raise ValueError(
                    f"output head {k} must be a (B, C, H, W) tensor, got {_describe(head)}"
                )
            if k == 0 and head.shape[-2:] != labels.shape[-2:]:
                raise ValueError(
                    f"output head 0 (the main output) must have the labels' spatial size "
                    f"{tuple(labels.shape[-2:])}, got {tuple(head.shape[-2:])}"
                )
            term = weight * self.loss(head, downsample_labels(labels, head.shape[-2:]))
            total = term if total is None else total + term
        assert total is not None
        return total
