"""Model cards: what a registered network *is*, kept next to the code that builds it.

A :class:`ModelCard` is the published description of one network for one label set, in the
spirit of timm's ``default_cfgs`` and torchvision's weights metadata: input size, classes and
their set, whether it reads depth, its input normalisation, the paper figures (as references to
the cells of ``evsmap/tables/paper_tables.toml``, never copied numbers) and the weight files that
are known to exist. The segmenter factories read their defaults from their cards, and the paper
tables name cards instead of repeating option sets (``segmenter = { card = "feagnet-v1" }``).

Not to be confused with :mod:`evsmap.segmenters.cards`: that is the *weights-file* card, the
record written beside a ``state_dict`` (what one file holds: model, options, tensors, training
run). A model card says what a network is before any file exists.

Names: a segmenter's default card, where it has one, is named after it (``feagnet-v1``: NYUv2,
40 classes); a card for another label set is ``<segmenter>.<dataset>`` (``feagnet-v1.sunrgbd``;
the baselines have only these, ``esanet-r34-nbt1d.nyuv2`` .. ``.cityscapes``, one per value of
their ``dataset`` option). :attr:`ModelCard.options` are the segmenter options that build
the card's network. :data:`MODEL_CARDS` is the registry: a taken name raises
:class:`~evsmap.errors.DuplicateNameError`, an unknown one
:class:`~evsmap.errors.UnknownNameError` with the closest name. The built-in cards are added by
:mod:`evsmap.segmenters.zoo`, the baselines' by their plug-in (``baselines.segmenters``); a
lookup loads them as the segmenter registry loads its plug-ins.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from evsmap.errors import DuplicateNameError, unknown_name

if TYPE_CHECKING:
    from evsmap.segmenters.normalization import Normalization

PAPER = ("EVSMaP: An Efficient Volumetric-Semantic Mapping Approach for Embedded Systems "
         "(../shared/paper/EVSMaP.md)")
"""The citation of the networks the paper introduces (FEAGNet)."""

CLASS_SETS: dict[str, int] = {"nyuv2-40": 40, "sunrgbd-37": 37, "cityscapes-19": 19}
"""Label set name -> classes (the sets of :func:`evsmap.classes.class_names_for`)."""

_NAME = re.compile(r"^[a-z0-9][a-z0-9_+-]*(\.[a-z0-9][a-z0-9_+-]*)?$")
_CELL = re.compile(r"^table[1-9]/[a-z0-9][a-z0-9_.+-]*/[a-z0-9][a-z0-9_.+-]*$")


@dataclass(frozen=True, kw_only=True)
class PaperFigure:
    """A published figure of the network, as a reference to its printed cell.

    Args:
        quantity: ``params``, ``flops``, ``miou`` or ``fps`` (the column's quantity).
        cell: ``table/row/column`` in ``paper_tables.toml`` (``table1/feagnet-v1/params``); the
            number, unit, input size and dataset are the cell's and its column's.
        note: what the reference needs said (e.g. the sentence of the text that repeats it).
    """

    quantity: str
    cell: str
    note: str = ""

    def __post_init__(self) -> None:
        if not _CELL.match(self.cell):
            raise ValueError(f"paper figure cell {self.cell!r} is not 'tableN/row/column'")

    @property
    def where(self) -> tuple[str, str, str]:
        """``(table, row, column)``."""
        table, row, column = self.cell.split("/")
        return table, row, column


@dataclass(frozen=True, kw_only=True)
class WeightFile:
    """A weights file known to exist for the network.

    Args:
        name: the file's name as released (``hardnet70_cityscapes_model.pkl``), or a description
            where the release names none.
        dataset: the data it was trained on.
        layout: its :data:`evsmap.segmenters.official.LAYOUTS` name (how evsmap reads it).
        source: where to get it (the releasing repository and where in it).
        url: a direct download address, when one is published.
        sha256: the file's hex sha256, when known.
        note: anything else a user needs (tensor count, conversion).
    """

    name: str
    dataset: str
    layout: str
    source: str
    url: str | None = None
    sha256: str | None = None
    note: str = ""


@dataclass(frozen=True, kw_only=True)
class ModelCard:
    """One network for one label set.

    Args:
        name: the card's name: the segmenter's name for its default card, else
            ``<segmenter>.<dataset>``.
        segmenter: the registered segmenter that builds it.
        description: one line for listings.
        citation: the paper that introduces the network.
        dataset: the dataset whose label set it predicts (and its weights are trained on).
        input_size: the default network input ``(height, width)`` of the built network.
        num_classes: classes of the classifier: the label set's, or one more where the head
            keeps the void class as class 0 (e.g. PGDENet's 41 on NYUv2).
        class_set: the label set's name (a key of :data:`CLASS_SETS`).
        uses_depth: reads depth besides RGB.
        normalization: how a frame is standardised before the network.
        options: segmenter options that build this card's network (``num_classes = 37``,
            ``dataset = "sunrgbd"``); empty for a segmenter's default card.
        published: the paper's figures for it (:class:`PaperFigure`); none where the paper
            prints none.
        weights: known weight files (:class:`WeightFile`).
        note: remarks (where a figure or a setting comes from).
    """

    name: str
    segmenter: str
    description: str
    citation: str
    dataset: str
    input_size: tuple[int, int]
    num_classes: int
    class_set: str
    uses_depth: bool
    normalization: Normalization = field(repr=False)
    options: tuple[tuple[str, Any], ...] = ()
    published: tuple[PaperFigure, ...] = ()
    weights: tuple[WeightFile, ...] = ()
    note: str = ""

    def __post_init__(self) -> None:
        if not _NAME.match(self.name):
            raise ValueError(f"model card name {self.name!r}: lower case letters, digits, "
                             "'_+-' and at most one '.'")
        if self.name.split(".")[0] != self.segmenter:
            raise ValueError(f"model card {self.name!r}: the name starts with its segmenter "
                             f"{self.segmenter!r}")
        if not (len(self.input_size) == 2 and all(int(s) > 0 for s in self.input_size)):
            raise ValueError(f"model card {self.name!r}: input_size is (height, width)")
        size = CLASS_SETS.get(self.class_set)
        if size is None or self.num_classes not in (size, size + 1):  # + 1: void kept
            raise ValueError(f"model card {self.name!r}: class set {self.class_set!r} does not "
                             f"have {self.num_classes} classes (known: {CLASS_SETS})")
        object.__setattr__(self, "options", tuple(sorted(dict(self.options).items())))

    @property
    def config(self) -> dict[str, Any]:
        """:attr:`options` as a dict (what ``SEGMENTERS.create`` takes)."""
        return dict(self.options)

    def figure(self, quantity: str) -> PaperFigure | None:
        """The published figure of ``quantity``, if the paper prints one."""
        return next((f for f in self.published if f.quantity == quantity), None)


class CardRegistry:
    """Names -> :class:`ModelCard` (see the module docstring for names and loading)."""

    def __init__(self) -> None:
        self._cards: dict[str, ModelCard] = {}

    def add(self, card: ModelCard) -> ModelCard:
        """Register ``card`` under its name.

        Raises:
            DuplicateNameError: the name is taken.
        """
        if card.name in self._cards:
            raise DuplicateNameError(f"model card {card.name!r} is already registered")
        self._cards[card.name] = card
        return card

    def remove(self, name: str) -> None:
        """Drop ``name`` (tests, plug-ins that replace their cards)."""
        self.get(name)
        del self._cards[name]

    def get(self, name: str) -> ModelCard:
        """The card ``name``.

        Raises:
            UnknownNameError: with the closest name and the known ones.
        """
        _load()
        try:
            return self._cards[name]
        except KeyError:
            pass
        raise unknown_name("model card", name, self._cards) from None

    def for_dataset(self, name: str, dataset: str | None) -> ModelCard:
        """Card ``name``, or its segmenter's card for ``dataset``'s label set when ``name``'s
        is another one (``feagnet-v1`` on ``sunrgbd`` is ``feagnet-v1.sunrgbd``). Without such a
        card (or without a dataset) it is ``name`` itself."""
        card = self.get(name)
        if dataset is None or card.dataset == dataset:
            return card
        same = [c for c in self._cards.values()
                if c.segmenter == card.segmenter and c.dataset == dataset]
        if not same:
            return card
        return next((c for c in same if c.name == card.segmenter), min(same, key=_by_name))

    def of_segmenter(self, segmenter: str) -> list[ModelCard]:
        """The cards of ``segmenter``, its default card first."""
        _load()
        cards = [c for c in self._cards.values() if c.segmenter == segmenter]
        return sorted(cards, key=lambda c: (c.name != segmenter, c.name))

    def names(self) -> list[str]:
        _load()
        return sorted(self._cards)

    def items(self) -> Mapping[str, ModelCard]:
        _load()
        return dict(sorted(self._cards.items()))

    def __contains__(self, name: object) -> bool:
        _load()
        return name in self._cards

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self.names())


def _by_name(card: ModelCard) -> str:
    return card.name


def _load() -> None:
    """Cards are registered by the modules that register the segmenters: load those."""
    from evsmap.registry import SEGMENTERS

    SEGMENTERS.names()


MODEL_CARDS = CardRegistry()
"""Every registered model card."""
