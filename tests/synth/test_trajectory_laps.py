"""Several laps of the room: the long sequence that revisits space, as a robot's run does."""

from __future__ import annotations

import numpy as np
import pytest

from evsmap.errors import EvsmapError
from evsmap.synth.sequence import SyntheticSequence
from evsmap.synth.trajectory import room_trajectory

ROOM = (6.0, 5.0, 2.7)


def test_one_lap_is_the_earlier_path():
    one = room_trajectory(ROOM, 40, seed=3)
    explicit = room_trajectory(ROOM, 40, seed=3, laps=1)
    for a, b in zip(one, explicit, strict=True):
        assert np.array_equal(a, b)


def test_laps_revisit_the_room_from_other_poses():
    n, laps = 120, 3
    _, eye, quats = room_trajectory(ROOM, n, seed=1, laps=laps)
    per_lap = n // laps
    centre = np.array(ROOM[:2]) / 2
    radius = np.linalg.norm(eye[:, :2] - centre, axis=1)
    # the same angle on lap 1 and lap 2: nearby (a revisit), not the same pose
    gap = np.linalg.norm(eye[:per_lap] - eye[per_lap:2 * per_lap], axis=1)
    assert 0.0 < gap.max() < 2.0
    assert radius[per_lap + per_lap // 2] < radius[per_lap // 8]  # the middle lap shrinks
    assert not np.allclose(quats[:per_lap], quats[per_lap:2 * per_lap])


def test_the_sequence_names_its_laps_and_checks_them():
    seq = SyntheticSequence(frames=6, width=16, height=12, laps=2)
    assert seq.name.endswith("-2laps") and len(seq) == 6
    with pytest.raises(EvsmapError, match="laps"):
        SyntheticSequence(frames=6, laps=0)
