"""Reading frames with ``--skip-bad``: a bad frame (corrupt image, wrong dtype, no pose at its
stamp, ...) either stops the run with its one-line error or, when the user asks, is skipped and
counted with its reason."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

from evsmap.data import Frame, Sequence
from evsmap.errors import EvsmapError


@dataclass
class SkippedFrames:
    """Frames left out by ``--skip-bad``: ``(index, reason)`` pairs in reading order."""

    frames: list[tuple[int, str]] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.frames)

    def as_dict(self) -> dict:
        return {"count": len(self.frames),
                "frames": [{"index": i, "reason": why} for i, why in self.frames]}

    def summary(self, limit: int = 5) -> str:
        """``"skipped 2 bad frames: #3 (reason); #7 (reason)"``, at most ``limit`` listed."""
        if not self.frames:
            return "skipped no frames"
        listed = "; ".join(f"#{i} ({why})" for i, why in self.frames[:limit])
        more = f"; and {len(self.frames) - limit} more" if len(self.frames) > limit else ""
        return f"skipped {len(self.frames)} bad frame(s): {listed}{more}"


def read_frames(sequence: Sequence, indices: Iterable[int], *, skip_bad: bool = False,
                skipped: SkippedFrames | None = None) -> Iterator[tuple[int, Frame]]:
    """``(index, frame)`` for each index. A frame whose reading raises an :class:`EvsmapError`
    stops the iteration with that error, or with ``skip_bad`` is recorded in ``skipped`` and
    left out."""
    for i in indices:
        try:
            frame = sequence.frame(i)
        except EvsmapError as exc:
            if not skip_bad:
                raise
            if skipped is not None:
                skipped.frames.append((int(i), str(exc)))
            continue
        yield i, frame
