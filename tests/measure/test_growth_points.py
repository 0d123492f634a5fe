"""How many growth snapshots a mapping run takes, and that the last frame's is taken on the
finished map (growth.finish inside the engine's reuse_tree), not in the loop."""

from evsmap.measure.growth import (
    GROWTH_POINTS,
    LONG_SEQUENCE,
    QUICK_GROWTH_POINTS,
    SHORT_GROWTH_POINTS,
    MapGrowth,
    growth_every,
    growth_points,
)


def test_points_by_length_and_quick():
    assert growth_points(LONG_SEQUENCE) == GROWTH_POINTS
    assert growth_points(60) == SHORT_GROWTH_POINTS == 2
    assert growth_points(LONG_SEQUENCE, quick=True) == growth_points(8, quick=True) == 1
    assert QUICK_GROWTH_POINTS == 1 and growth_every(8, 1) == 8


def test_a_quick_run_snapshots_the_finished_map_once(monkeypatch):
    import evsmap.measure.growth as growth

    taken = []
    monkeypatch.setattr(growth, "snapshot", lambda frames, updater: taken.append(frames) or
                        {"frames": frames})
    g = MapGrowth(every=growth_every(8, growth_points(8, quick=True)))
    for frames in range(1, 8):  # the engine's loop calls after_frame before the last frame
        g.after_frame(frames, None)
    assert taken == []
    assert g.finish(8, None) == [{"frames": 8}]
