"""Tests of evsmap.losses against numbers worked out by hand.

The basic case used throughout is one image of 1 x 2 pixels and C = 2 classes:

    pixel 0: logits (0, log 3)  -> p = (1/4, 3/4), label 1
    pixel 1: logits (0, 0)      -> p = (1/2, 1/2), label 0
"""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from evsmap.data import VOID
from evsmap.losses import (
    DiceLoss,
    HybridLoss,
    MultiScaleLoss,
    SoftCrossEntropyLoss,
    downsample_labels,
)

LOG3 = math.log(3.0)
LOG2 = math.log(2.0)

# Dice, class 0: y = (0, 1), p = (1/4, 1/2): 2*sum(yp) = 2*(1/2) = 1,
#   sum p^2 = 1/16 + 1/4 = 5/16, sum y^2 = 1  ->  1 - 1 / (21/16) = 1 - 16/21 = 5/21
# Dice, class 1: y = (1, 0), p = (3/4, 1/2): 2*sum(yp) = 3/2,
#   sum p^2 = 9/16 + 4/16 = 13/16, sum y^2 = 1  ->  1 - (3/2) / (29/16) = 1 - 24/29 = 5/29
# mean over the two classes: (5/21 + 5/29) / 2 = (145 + 105) / (2 * 609) = 125/609
DICE_BASIC = 125 / 609  # 0.2052545...
# SCE: -(log(3/4) + log(1/2)) / 2 = (log(4/3) + log 2) / 2 = log(8/3) / 2
SCE_BASIC = 0.5 * math.log(8 / 3)  # 0.4904146...


def basic_case(dtype=torch.float32):
    logits = torch.tensor([[[[0.0, 0.0]], [[LOG3, 0.0]]]], dtype=dtype)  # (1, 2, 1, 2)
    labels = torch.tensor([[[1, 0]]])  # (1, 1, 2)
    return logits, labels


def with_void_pixel(void_logits=(5.0, -7.0), dtype=torch.float32):
    """The basic case plus a third, void pixel with the given logits."""
    logits, labels = basic_case(dtype)
    extra = torch.tensor(void_logits, dtype=dtype).view(1, 2, 1, 1)
    return torch.cat([logits, extra], dim=3), torch.tensor([[[1, 0, VOID]]])


ALL_LOSSES = [
    pytest.param(lambda: DiceLoss(), DICE_BASIC, id="dice"),
    pytest.param(lambda: SoftCrossEntropyLoss(), SCE_BASIC, id="sce"),
    pytest.param(lambda: HybridLoss(), DICE_BASIC + SCE_BASIC, id="hybrid"),
    pytest.param(lambda: MultiScaleLoss(loss=HybridLoss()), DICE_BASIC + SCE_BASIC,
                 id="multiscale"),
]


def test_void_constant():
    assert VOID == 255


def test_softmax_of_basic_case_is_as_stated():
    logits, _ = basic_case(torch.float64)
    p = torch.softmax(logits, dim=1)[0, :, 0]
    torch.testing.assert_close(p, torch.tensor([[0.25, 0.5], [0.75, 0.5]], dtype=torch.float64))


# --- values computed by hand ------------------------------------------------------------------


def test_dice_hand_computed():
    logits, labels = basic_case()
    assert DiceLoss()(logits, labels).item() == pytest.approx(DICE_BASIC, abs=1e-6)


def test_dice_per_class_terms_hand_computed():
    terms, present = DiceLoss().per_class(*basic_case(torch.float64))
    torch.testing.assert_close(terms, torch.tensor([5 / 21, 5 / 29], dtype=torch.float64))
    assert present.tolist() == [True, True]


def test_dice_smooth_hand_computed():
    # smooth = 1: class 0: 1 - (1 + 1) / (21/16 + 1) = 1 - 32/37 = 5/37
    #             class 1: 1 - (3/2 + 1) / (29/16 + 1) = 1 - 40/45 = 1/9
    # mean: (5/37 + 1/9) / 2 = (45 + 37) / 666 = 41/333
    logits, labels = basic_case()
    loss = DiceLoss(smooth=1.0)(logits, labels)
    assert loss.item() == pytest.approx(41 / 333, abs=1e-6)


def test_dice_absent_class_is_left_out_of_the_mean():
    # C = 3, both pixels labelled 0, classes 1 and 2 absent.
    #   pixel 0: logits (log 2, 0, 0) -> p = (1/2, 1/4, 1/4)
    #   pixel 1: logits (0, 0, log 2) -> p = (1/4, 1/4, 1/2)
    # class 0: y = (1, 1), p = (1/2, 1/4): 2*sum(yp) = 3/2, sum p^2 = 5/16, sum y^2 = 2
    #   -> 1 - (3/2) / (37/16) = 1 - 24/37 = 13/37
    # Present classes only: 13/37 = 0.35135. (All three classes would give (13/37 + 1 + 1) / 3
    # = 87/111 = 0.78378, since an absent class's term is 1 - 0 / (...) = 1.)
    logits = torch.tensor([[[[LOG2, 0.0]], [[0.0, 0.0]], [[0.0, LOG2]]]], requires_grad=True)
    labels = torch.tensor([[[0, 0]]])
    loss = DiceLoss()(logits, labels)
    assert loss.item() == pytest.approx(13 / 37, abs=1e-6)
    assert loss.item() != pytest.approx(87 / 111, abs=1e-3)
    terms, present = DiceLoss().per_class(logits, labels)
    assert present.tolist() == [True, False, False]
    torch.testing.assert_close(terms[1:], torch.ones(2))  # constant, no gradient
    # the absent classes are still pushed down through the softmax: descent lowers their logits
    loss.backward()
    assert (logits.grad[0, 1:] > 0).all()
    assert (logits.grad[0, 0] < 0).all()


def test_dice_is_computed_over_the_whole_batch():
    # Two 1x1 images holding the two pixels of the basic case give the same sums, so the same
    # value as the 1x2 image (batch-level Dice, not a mean of per-image Dice values).
    logits, labels = basic_case()
    batched = logits.permute(3, 1, 2, 0)  # (2, 2, 1, 1)
    batched_labels = labels.permute(2, 1, 0)  # (2, 1, 1)
    assert DiceLoss()(batched, batched_labels).item() == pytest.approx(DICE_BASIC, abs=1e-6)


def test_sce_hand_computed():
    logits, labels = basic_case()
    assert SoftCrossEntropyLoss()(logits, labels).item() == pytest.approx(SCE_BASIC, abs=1e-6)


def test_sce_label_smoothing_hand_computed():
    # smooth_factor = 0.2, C = 2: q = 0.8 * onehot + 0.1
    #   pixel 0 (label 1): q = (0.1, 0.9): -(0.1 log 1/4 + 0.9 log 3/4) = 0.1 log 4 + 0.9 log 4/3
    #   pixel 1 (label 0): q = (0.9, 0.1), p = (1/2, 1/2): -log 1/2 = log 2
    # mean: (0.1 * 1.3862944 + 0.9 * 0.2876821 + 0.6931472) / 2 = 1.0906905 / 2 = 0.5453452
    expected = (0.1 * math.log(4) + 0.9 * math.log(4 / 3) + LOG2) / 2
    logits, labels = basic_case()
    loss = SoftCrossEntropyLoss(smooth_factor=0.2)(logits, labels)
    assert loss.item() == pytest.approx(expected, abs=1e-6)
    assert expected == pytest.approx(0.5453452, abs=1e-7)


def test_hybrid_hand_computed():
    logits, labels = basic_case()
    # alpha = beta = 1: 125/609 + log(8/3)/2 = 0.2052545 + 0.4904146 = 0.6956691
    assert HybridLoss()(logits, labels).item() == pytest.approx(0.6956691, abs=1e-6)
    # alpha = 2, beta = 0.5: 2 * 0.2052545 + 0.5 * 0.4904146 = 0.6557163
    loss = HybridLoss(alpha=2.0, beta=0.5)(logits, labels)
    assert loss.item() == pytest.approx(2 * DICE_BASIC + 0.5 * SCE_BASIC, abs=1e-6)
    assert loss.item() == pytest.approx(0.6557163, abs=1e-6)


def test_half_precision_logits_are_upcast():
    logits, labels = basic_case()
    loss = HybridLoss()(logits.to(torch.bfloat16), labels)
    assert loss.dtype == torch.float32
    # bfloat16 rounds log 3 to 1.09375, so only a loose match
    assert loss.item() == pytest.approx(DICE_BASIC + SCE_BASIC, abs=5e-3)


# --- void pixels ----------------------------------------------------------------------------


@pytest.mark.parametrize(("make", "expected"), ALL_LOSSES)
def test_void_pixel_is_ignored(make, expected):
    loss_fn = make()
    for void_logits in [(5.0, -7.0), (0.0, 0.0), (-30.0, 40.0), (math.inf, math.nan)]:
        logits, labels = with_void_pixel(void_logits)
        logits.requires_grad_(True)
        loss = loss_fn(logits, labels)
        assert loss.item() == pytest.approx(expected, abs=1e-6)
        loss.backward()
        assert torch.isfinite(logits.grad).all()
        assert (logits.grad[..., 2] == 0).all()  # the void pixel gets no gradient


@pytest.mark.parametrize(("make", "expected"), ALL_LOSSES)
def test_all_void_gives_zero_loss_and_zero_gradient(make, expected):
    logits = torch.randn(2, 3, 4, 5, requires_grad=True)
    labels = torch.full((2, 4, 5), VOID)
    loss = make()(logits, labels)
    assert loss.item() == 0.0
    loss.backward()
    assert logits.grad is not None
    assert torch.equal(logits.grad, torch.zeros_like(logits))


def test_void_pixels_do_not_count_in_n():
    # A single non-void pixel with p = 3/4 for its class among many void pixels: loss -log(3/4).
    logits = torch.zeros(1, 2, 3, 3)
    logits[0, 1, 1, 1] = LOG3
    labels = torch.full((1, 3, 3), VOID)
    labels[0, 1, 1] = 1
    assert SoftCrossEntropyLoss()(logits, labels).item() == pytest.approx(math.log(4 / 3),
                                                                          abs=1e-6)


# --- cross-checks on random data ------------------------------------------------------------


def random_case(seed, shape=(2, 4, 5, 6), void_fraction=0.3):
    gen = torch.Generator().manual_seed(seed)
    b, c, h, w = shape
    logits = torch.randn(shape, generator=gen, dtype=torch.float64) * 3
    labels = torch.randint(0, c, (b, h, w), generator=gen)
    labels[torch.rand((b, h, w), generator=gen) < void_fraction] = VOID
    return logits, labels


@pytest.mark.parametrize("smooth_factor", [0.0, 0.1, 0.5])
def test_sce_matches_torch_cross_entropy(smooth_factor):
    logits, labels = random_case(0)
    expected = F.cross_entropy(logits, labels, ignore_index=VOID, label_smoothing=smooth_factor)
    actual = SoftCrossEntropyLoss(smooth_factor=smooth_factor)(logits, labels)
    torch.testing.assert_close(actual, expected)


def test_dice_matches_a_plain_loop():
    logits, labels = random_case(1)
    labels[labels == 3] = 1  # make class 3 absent
    probs = torch.softmax(logits, dim=1)
    terms = []
    for c in range(logits.shape[1]):
        inter = sq_p = sq_y = 0.0
        for b, y, x in torch.nonzero(labels != VOID).tolist():
            p = probs[b, c, y, x].item()
            t = 1.0 if labels[b, y, x].item() == c else 0.0
            inter += t * p
            sq_p += p * p
            sq_y += t * t
        if sq_y > 0:
            terms.append(1 - 2 * inter / (sq_p + sq_y))
    assert len(terms) == 3
    expected = sum(terms) / len(terms)
    assert DiceLoss()(logits, labels).item() == pytest.approx(expected, abs=1e-12)


# --- gradients ------------------------------------------------------------------------------


def test_hybrid_gradcheck():
    logits, labels = random_case(2, shape=(1, 3, 3, 3))
    logits.requires_grad_(True)
    loss_fn = HybridLoss(smooth_factor=0.1)
    assert torch.autograd.gradcheck(lambda x: loss_fn(x, labels), (logits,))


def test_gradients_flow_to_every_head_and_are_finite():
    gen = torch.Generator().manual_seed(3)
    main = torch.randn(2, 4, 8, 8, generator=gen, requires_grad=True)
    side = torch.randn(2, 4, 4, 4, generator=gen, requires_grad=True)
    side2 = torch.randn(2, 4, 2, 2, generator=gen, requires_grad=True)
    labels = torch.randint(0, 4, (2, 8, 8), generator=gen)
    labels[:, :3] = VOID
    loss = MultiScaleLoss(loss=HybridLoss())((main, side, side2), labels)
    loss.backward()
    for head in (main, side, side2):
        assert torch.isfinite(head.grad).all()
        assert head.grad.abs().sum() > 0


# --- multi-scale ----------------------------------------------------------------------------


def test_downsample_labels_half_resolution_takes_top_left_of_each_block():
    labels = torch.tensor([[[0, 1, 2, 0],
                            [1, 1, 2, 2],
                            [VOID, 2, 1, 0],
                            [0, 0, 1, 1]]])
    small = downsample_labels(labels, (2, 2))
    assert small.dtype == torch.int64
    assert small.tolist() == [[[0, 2], [VOID, 1]]]
    assert torch.equal(small, labels[:, ::2, ::2])


def test_downsample_labels_other_sizes():
    labels = torch.arange(25).view(1, 5, 5)
    labels[0, 0, 0] = VOID
    # 5 -> 2: source index floor(i * 5/2) = 0, 2
    assert downsample_labels(labels, (2, 2)).tolist() == [[[VOID, 2], [10, 12]]]
    # 5 -> (1, 3): rows 0; columns floor(j * 5/3) = 0, 1, 3
    assert downsample_labels(labels, (1, 3)).tolist() == [[[VOID, 1, 3]]]
    assert downsample_labels(labels, (5, 5)) is labels


def test_multiscale_hand_computed():
    # main head: zero logits everywhere, labels (0, 1 / VOID, VOID) -> p = 1/2 at both non-void
    #   pixels -> SCE = log 2
    # side head at half resolution (1x1) gets the top-left label 0; logits (0, log 3) ->
    #   p_0 = 1/4 -> SCE = log 4 (had it picked label 1 instead it would be log(4/3))
    main = torch.zeros(1, 2, 2, 2)
    side = torch.tensor([0.0, LOG3]).view(1, 2, 1, 1)
    labels = torch.tensor([[[0, 1], [VOID, VOID]]])
    sce = SoftCrossEntropyLoss()
    # weights (1, 1): log 2 + log 4 = 3 log 2 = 2.0794415
    loss = MultiScaleLoss(loss=sce)((main, side), labels)
    assert loss.item() == pytest.approx(3 * LOG2, abs=1e-6)
    # weights (1, 0.5): log 2 + 0.5 log 4 = 2 log 2 = 1.3862944
    loss = MultiScaleLoss(loss=sce, weights=[1.0, 0.5])([main, side], labels)
    assert loss.item() == pytest.approx(2 * LOG2, abs=1e-6)
    # weights (0, 1): the side head alone
    loss = MultiScaleLoss(loss=sce, weights=(0, 1))((main, side), labels)
    assert loss.item() == pytest.approx(2 * LOG2, abs=1e-6)


def test_multiscale_side_head_with_void_top_left_contributes_nothing():
    main = torch.zeros(1, 2, 2, 2)
    side = torch.tensor([0.0, LOG3]).view(1, 2, 1, 1)
    labels = torch.tensor([[[VOID, 1], [0, 1]]])  # the side head's label is void
    loss = MultiScaleLoss(loss=SoftCrossEntropyLoss())((main, side), labels)
    assert loss.item() == pytest.approx(LOG2, abs=1e-6)


def test_multiscale_equals_sum_of_heads_against_downsampled_labels():
    logits, labels = random_case(4, shape=(2, 3, 8, 8))
    logits = logits.float()
    side = torch.randn(2, 3, 4, 4, dtype=torch.float32)
    hybrid = HybridLoss()
    expected = hybrid(logits, labels) + 0.4 * hybrid(side, labels[:, ::2, ::2])
    actual = MultiScaleLoss(loss=hybrid, weights=[1.0, 0.4])((logits, side), labels)
    torch.testing.assert_close(actual, expected)


def test_multiscale_single_tensor_is_one_head():
    logits, labels = basic_case()
    assert MultiScaleLoss(loss=DiceLoss())(logits, labels).item() == pytest.approx(DICE_BASIC,
                                                                                   abs=1e-6)
    loss = MultiScaleLoss(loss=DiceLoss(), weights=[2.0])(logits, labels)
    assert loss.item() == pytest.approx(2 * DICE_BASIC, abs=1e-6)


# --- errors ---------------------------------------------------------------------------------


LOGITS = torch.zeros(1, 2, 1, 2)
LABELS = torch.tensor([[[1, 0]]])


INPUT_ERRORS = {
    "logits-3d": (torch.zeros(2, 1, 2), LABELS,
                  r"logits must have shape \(B, C, H, W\), got \(2, 1, 2\)"),
    "logits-int": (torch.zeros(1, 2, 1, 2, dtype=torch.int64), LABELS,
                   "logits must be a floating-point tensor, got torch.int64"),
    "labels-float": (LOGITS, LABELS.float(),
                     r"labels must be int64 \(torch.long\), got torch.float32"),
    "labels-int32": (LOGITS, LABELS.int(), r"labels must be int64 \(torch.long\), got torch.int32"),
    "labels-2d": (LOGITS, torch.tensor([[1, 0]]),
                  r"labels must have shape \(B, H, W\) = \(1, 1, 2\) .* got \(1, 2\)"),
    "labels-wider": (LOGITS, torch.tensor([[[1, 0, 0]]]), r"got \(1, 1, 3\)"),
    "labels-batch": (LOGITS, torch.tensor([[[1, 0]], [[0, 1]]]), r"got \(2, 1, 2\)"),
    "label-eq-c": (LOGITS, torch.tensor([[[2, 0]]]),
                   r"labels must be class ids in \[0, 2\) or void \(255\), found 2"),
    "label-negative": (LOGITS, torch.tensor([[[-1, 0]]]), "found -1"),
    "label-254": (LOGITS, torch.tensor([[[254, VOID]]]), "found 254"),
    "logits-numpy": (LOGITS.numpy(), LABELS,
                     "logits and labels must be torch tensors, got ndarray and Tensor"),
}

# MultiScaleLoss checks the heads and the labels' rank itself, so words some cases differently
MULTISCALE_MESSAGES = {
    "logits-3d": r"output head 0 must be a \(B, C, H, W\) tensor, got \(2, 1, 2\)",
    "labels-2d": r"labels must be a \(B, H, W\) tensor, got \(1, 2\)",
    "labels-wider": r"output head 0 \(the main output\) must have the labels' spatial size "
                    r"\(1, 3\), got \(1, 2\)",
    "logits-numpy": "output head 0 must be a .* tensor, got ndarray",
}


@pytest.mark.parametrize("case", list(INPUT_ERRORS))
@pytest.mark.parametrize("name", ["dice", "sce", "hybrid", "multiscale"])
def test_input_errors(name, case):
    logits, labels, message = INPUT_ERRORS[case]
    loss_fn = {
        "dice": DiceLoss(),
        "sce": SoftCrossEntropyLoss(),
        "hybrid": HybridLoss(),
        "multiscale": MultiScaleLoss(loss=HybridLoss()),
    }[name]
    if name == "multiscale":
        message = MULTISCALE_MESSAGES.get(case, message)
    with pytest.raises(ValueError, match=message):
        loss_fn(logits, labels)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: DiceLoss(eps=0.0), r"eps must be a finite number in \(0, inf\), got 0.0"),
        (lambda: DiceLoss(smooth=-1), r"smooth must be a finite number in \[0, inf\)"),
        (lambda: DiceLoss(smooth=math.nan), "smooth must be a finite number"),
        (lambda: SoftCrossEntropyLoss(smooth_factor=1.0),
         r"smooth_factor must be a finite number in \[0, 1\), got 1.0"),
        (lambda: SoftCrossEntropyLoss(smooth_factor="0.1"), "smooth_factor must be a number"),
        (lambda: HybridLoss(alpha=-1.0), "alpha must be a finite number"),
        (lambda: HybridLoss(beta=math.inf), "beta must be a finite number"),
        (lambda: MultiScaleLoss(loss=HybridLoss(), weights=[1.0, -0.5]),
         r"weights\[1\] must be a finite number in \[0, inf\)"),
        (lambda: MultiScaleLoss(loss=HybridLoss(), weights=[]), "weights must not be empty"),
        (lambda: MultiScaleLoss(loss=HybridLoss(), weights=0.5), "weights must be a sequence"),
        (lambda: MultiScaleLoss(loss="hybrid"), "loss must be callable"),
    ],
)
def test_constructor_errors(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_constructors_are_keyword_only():
    with pytest.raises(TypeError):
        DiceLoss(1.0)
    with pytest.raises(TypeError):
        SoftCrossEntropyLoss(0.1)
    with pytest.raises(TypeError):
        HybridLoss(1.0, 1.0)
    with pytest.raises(TypeError):
        MultiScaleLoss(HybridLoss())


def test_multiscale_errors():
    logits, labels = basic_case()
    with pytest.raises(ValueError, match="got 2 output heads but 3 weights"):
        MultiScaleLoss(loss=DiceLoss(), weights=[1, 1, 1])((logits, logits), labels)
    with pytest.raises(ValueError, match="outputs must hold at least one logit map"):
        MultiScaleLoss(loss=DiceLoss())((), labels)
    with pytest.raises(ValueError, match=r"output head 1 must be a \(B, C, H, W\) tensor"):
        MultiScaleLoss(loss=DiceLoss())((logits, logits[0]), labels)
    with pytest.raises(ValueError, match=r"labels must be int64"):
        MultiScaleLoss(loss=DiceLoss())((logits, logits[..., :1]), labels.int())
    # the main head must be at label resolution; only side heads are compared with resized labels
    with pytest.raises(ValueError, match=r"output head 0 \(the main output\) must have"):
        MultiScaleLoss(loss=DiceLoss())((logits[..., :1], logits), labels)
    # a side head with another batch size is caught by the per-head loss
    with pytest.raises(ValueError, match=r"labels must have shape \(B, H, W\) = \(2, 1, 1\)"):
        MultiScaleLoss(loss=DiceLoss())((logits, logits[..., :1].expand(2, -1, -1, -1)), labels)


def test_downsample_labels_errors():
    with pytest.raises(ValueError, match=r"labels must be a \(B, H, W\) tensor, got \(4, 4\)"):
        downsample_labels(torch.zeros(4, 4, dtype=torch.int64), (2, 2))
    with pytest.raises(ValueError, match="labels must be int64"):
        downsample_labels(torch.zeros(1, 4, 4, dtype=torch.uint8), (2, 2))
    with pytest.raises(ValueError, match="size must be two positive integers"):
        downsample_labels(torch.zeros(1, 4, 4, dtype=torch.int64), (0, 2))


def test_hybrid_shared_softmax_equals_its_two_terms_called_apart():
    """HybridLoss computes one log-softmax for both terms; value and gradient must equal
    alpha * DiceLoss + beta * SoftCrossEntropyLoss called separately (void pixels included)."""
    g = torch.Generator().manual_seed(5)
    logits = torch.randn(3, 6, 9, 11, generator=g, dtype=torch.float64)
    labels = torch.randint(0, 6, (3, 9, 11), generator=g)
    labels[1, :4] = VOID
    labels[labels == 2] = 0  # class 2 absent: left out of the Dice mean
    fused_in = logits.clone().requires_grad_()
    apart_in = logits.clone().requires_grad_()
    hybrid = HybridLoss(alpha=0.7, beta=1.3, smooth_factor=0.1, dice_smooth=0.25)
    fused = hybrid(fused_in, labels)
    apart = 0.7 * DiceLoss(smooth=0.25)(apart_in, labels) + 1.3 * SoftCrossEntropyLoss(
        smooth_factor=0.1)(apart_in, labels)
    fused.backward()
    apart.backward()
    assert float(fused) == pytest.approx(float(apart), rel=1e-12)
    assert torch.allclose(fused_in.grad, apart_in.grad, rtol=1e-10, atol=1e-14)
    assert float(fused_in.grad[1, :, :4].abs().sum()) == 0.0
