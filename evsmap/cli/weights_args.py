"""The command line's one weights policy, for ``map``, ``eval``, ``predict`` and ``speed``
(``reproduce`` takes a folder of them, ``--weights DIR``):

``--weights FILE``
    the network's trained weights (a state dict or an official release checkpoint).
``--allow-random``
    run a network without trained weights: its random initialisation, drawn from ``--seed``.
``--seed S``
    the seed of that random initialisation (default 0,
    :data:`evsmap.segmenters.create.RANDOM_INIT_SEED`): the same seed, the same weights, so the
    same command gives the same result.

Where a command's result depends on the weights (``eval``'s scores, ``predict``'s labels, the
classes in a semantic ``map``), a network without ``--weights`` is refused unless
``--allow-random``, and a warning says the result is noise when it runs. Where it does not
(``speed``'s timing, a ``map`` whose updater reads no semantics) the random weights run without
``--allow-random`` and one note says so (``--allow-random`` silences it). Every record states
``weights``, ``random_weights`` and ``init_seed`` (:func:`evsmap.segmenters.create.weights_fields`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from evsmap.cli.options import nonnegative_int
from evsmap.errors import EvsmapError


def add_weights_options(p: argparse.ArgumentParser, *, depends: str | None) -> None:
    """``--weights``, ``--allow-random`` and ``--seed``; ``depends``: what of this command's
    result depends on the weights (None: nothing does), for the help."""
    p.add_argument("--weights", type=Path, metavar="FILE",
                   help="the network's trained weights (a state dict or an official release "
                        "checkpoint; `evsmap weights show FILE` checks one)")
    if depends:
        allow = (f"run a network without --weights: its random initialisation (seeded by "
                 f"--seed). {depends} then mean nothing; for checking the pipeline")
    else:
        allow = ("run a network without --weights without the note that says so (its seeded "
                 "random initialisation runs either way: nothing measured here depends on "
                 "the weights)")
    p.add_argument("--allow-random", action="store_true", help=allow)
    p.add_argument("--seed", type=nonnegative_int, default=0, metavar="S",
                   help="seed of a network's random initialisation when it runs without "
                        "--weights (default 0: the same seed, the same weights)")


def make_segmenter(args: argparse.Namespace, name: str, config: dict[str, Any], *,
                   command: str, depends: bool, noise: str = "") -> tuple[Any, dict[str, Any]]:
    """The segmenter ``name`` with ``config`` and the command's weights options applied, and the
    record's weights fields.

    Args:
        command: ``"evsmap eval"`` etc., for the stderr lines.
        depends: whether this run's result depends on the weights (then a network without
            ``--weights`` is refused unless ``--allow-random``).
        noise: what random weights make meaningless, as a clause (e.g. "its mIoU means
            nothing"), for the refusal and the warning.

    Raises:
        EvsmapError: ``--weights`` for a segmenter that takes none, or random weights refused.
    """
    from evsmap.registry import SEGMENTERS
    from evsmap.segmenters.create import create_segmenter, weights_fields

    config = dict(config)
    weights = getattr(args, "weights", None)
    if weights is not None:
        if not SEGMENTERS.get(name).takes.weights:
            raise EvsmapError(f"--weights {weights}: {name} is not a network and takes no "
                              f"weights (drop --weights)")
        if weights.is_dir():
            raise EvsmapError(f"--weights {weights}: is a folder; give the weights file")
        config["weights"] = str(weights)
    seed = getattr(args, "seed", 0)
    segmenter = create_segmenter(name, init_seed=seed, **config)
    fields = weights_fields(segmenter, seed)
    if fields["random_weights"] and depends and not getattr(args, "allow_random", False):
        raise EvsmapError(f"{name} has no trained weights: pass --weights FILE (or "
                          f"--allow-random to run its random initialisation, seed {seed}: "
                          f"{noise or 'its output would be noise'})")
    return segmenter, fields


def announce_weights(args: argparse.Namespace, name: str, fields: dict[str, Any], *,
                     command: str, depends: bool, noise: str = "") -> None:
    """The stderr line of a network running random weights (the warning where the result
    depends on them, else a note unless ``--allow-random``); call it once the command's own
    checks passed, so that an error comes alone."""
    if not fields.get("random_weights"):
        return
    seed = fields["init_seed"]
    if depends:
        sys.stderr.write(f"{command}: warning: {name} runs with RANDOM weights (seed {seed}, "
                         f"no --weights): {noise or 'its output is noise'}\n")
    elif not getattr(args, "allow_random", False):
        sys.stderr.write(f"{command}: note: {name} runs its random initialisation (seed {seed}, "
                         f"no --weights); nothing measured here depends on the weights\n")
