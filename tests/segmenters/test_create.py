"""The weights policy's home: an untrained network's random initialisation is drawn from a
seed, the same seed gives the same weights, and the caller's random stream is left alone."""

import torch

from evsmap.segmenters.create import RANDOM_INIT_SEED, create_segmenter, weights_fields


def _params(segmenter) -> list[torch.Tensor]:
    return [p.detach().clone() for p in segmenter.module.parameters()]


def _same(a, b) -> bool:
    return all(torch.equal(x, y) for x, y in zip(a, b, strict=True))


def test_same_seed_same_weights_other_seed_other_weights():
    first = _params(create_segmenter("feagnet-v1"))
    again = _params(create_segmenter("feagnet-v1", init_seed=RANDOM_INIT_SEED))
    other = _params(create_segmenter("feagnet-v1", init_seed=7))
    assert _same(first, again)
    assert not _same(first, other)


def test_the_callers_random_stream_is_untouched():
    torch.manual_seed(123)
    expected = torch.rand(4)
    torch.manual_seed(123)
    create_segmenter("feagnet-v1", init_seed=5)
    assert torch.equal(torch.rand(4), expected)


def test_weights_fields_state_the_seed_only_for_random_weights():
    network = create_segmenter("feagnet-v1", init_seed=4)
    assert weights_fields(network, 4) == {"weights": None, "random_weights": True,
                                          "init_seed": 4}
    oracle = create_segmenter("oracle", seed=2)  # the oracle's own noise seed, not the init's
    assert weights_fields(oracle, 4) == {"weights": None, "random_weights": False,
                                         "init_seed": None}
