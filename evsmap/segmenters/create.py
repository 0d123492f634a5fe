"""Making a segmenter with evsmap's one weights policy (the home of its facts).

* Trained weights are a file (``weights``), loaded strictly (:mod:`evsmap.segmenters.weights`).
* A network made without them gets a **random initialisation drawn from a seed**
  (:data:`RANDOM_INIT_SEED` unless given): the same seed, the same weights, so two runs of one
  command with one untrained network give the same result, byte for byte. The seed is drawn in
  a forked copy of torch's generator, so the caller's own random stream is left as it was.
* Every record says which it was: :func:`weights_fields` (``weights``, ``random_weights``,
  ``init_seed``).

Which commands refuse random weights and which use them is the command line's policy
(:mod:`evsmap.cli.weights_args`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from evsmap.interfaces import Segmenter

RANDOM_INIT_SEED = 0
"""The seed of an untrained network's random initialisation when none is given."""


def create_segmenter(name: str, *, init_seed: int = RANDOM_INIT_SEED, **config: Any) -> Any:
    """``SEGMENTERS.create(name, **config)`` with a network's random initialisation drawn from
    ``init_seed`` (weights given in ``config["weights"]`` replace it; a segmenter's own ``seed``
    option, e.g. the oracle's noise, is another thing and goes in ``config``)."""
    import torch

    from evsmap.registry import SEGMENTERS

    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(int(init_seed))
        return SEGMENTERS.create(name, **config)


def is_network(segmenter: Segmenter) -> bool:
    """Whether ``segmenter`` runs a network (and so has weights, trained or random)."""
    return segmenter.module is not None


def weights_fields(segmenter: Segmenter, seed: int) -> dict[str, Any]:
    """What a record states about a segmenter's weights: ``weights`` (the file, or None),
    ``random_weights`` (a network without trained weights) and ``init_seed`` (the seed of those
    random weights; None where the weights came from a file or there is no network)."""
    weights = segmenter.weights
    random_weights = is_network(segmenter) and weights is None
    return {"weights": weights, "random_weights": random_weights,
            "init_seed": int(seed) if random_weights else None}
