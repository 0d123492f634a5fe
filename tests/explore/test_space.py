"""The search space file: the shipped space's defaults are the paper's (the registered updater's
and Table IV's), and every way a file can be wrong is one line naming the file and the entry."""

from __future__ import annotations

from pathlib import Path

import pytest

from evsmap.explore.space import SpaceError, load_space, shipped_space
from tests.explore.conftest import SMALL_SPACE


def test_shipped_space_defaults_are_what_table_iv_runs_with() -> None:
    from evsmap.mapping.fusion.mcb import PROB_MAX, PROB_MIN
    from evsmap.registry import UPDATERS
    from evsmap.tables.schema import mapping_table

    path = shipped_space("multiclass-bayes")
    assert path is not None
    space = load_space(path)
    defaults = space.defaults()
    params = UPDATERS.get("multiclass-bayes").options
    for name in ("psi", "phi", "theta", "raycast_range", "max_range"):
        assert defaults[name] == pytest.approx(params[name].default), name
    # the clamps are left to the generator (None in the factory): SSMI's yaml values
    assert (defaults["clamp_min"], defaults["clamp_max"]) == (PROB_MIN, PROB_MAX)
    voxel = {c.resolution for c in mapping_table().columns}
    assert voxel == {defaults["resolution"]}
    assert [o.name for o in space.objectives] == ["map_size", "scene_miou"]
    assert space.baseline == "tesamap"


def test_split_sends_shared_settings_to_every_map(small_space) -> None:
    shared, own = small_space.split(small_space.defaults())
    assert shared == {"resolution": 0.1, "raycast_range": 2.0}
    assert own == {"psi": 1.0, "theta": 0.6}


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "space.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(("edit", "expected"), [
    (lambda t: t.replace('name = "psi"', 'name = "psy"'), "multiclass-bayes has no option 'psy'"),
    (lambda t: t.replace("low = 1.0\nhigh = 3.0", "low = -1.0\nhigh = 3.0"),
     "raycast_range = -1.0 is refused by multiclass-bayes"),
    (lambda t: t.split("[[parameters]]")[0], "the space is empty"),
    (lambda t: t.replace("default = 0.6", "default = 2.6"), "outside [0, 1.5]"),
    (lambda t: t.replace('name = "scene_miou"', 'name = "iou"'), "unknown objective 'iou'"),
    (lambda t: t.replace("low = 0.0\nhigh = 1.5", "low = 1.5\nhigh = 1.5"), "is empty"),
    (lambda t: t.replace('updater = "multiclass-bayes"', 'updater = "nope"'),
     "updater 'nope' is not registered"),
    (lambda t: t.replace('name = "theta"', 'name = "psi"'), "'psi' is given twice"),
    (lambda t: t.replace('name = "tpe"', 'name = "cmaes"'), "name must be one of tpe, nsga2"),
    (lambda t: t + "\n[extra]\n", "unknown entry 'extra'"),
    (lambda t: t.replace("[sampler]", "[sampler"), "not valid TOML"),
])
def test_bad_space_is_one_line_naming_the_file(tmp_path: Path, edit, expected) -> None:
    path = _write(tmp_path, edit(SMALL_SPACE))
    with pytest.raises(SpaceError) as info:
        load_space(path)
    message = str(info.value)
    assert str(path) in message and expected in message
    assert "\n" not in message


def test_size_ratio_needs_a_baseline(tmp_path: Path) -> None:
    steered = SMALL_SPACE + '\n[[objectives]]\nname = "size_ratio"\n'
    assert [o.name for o in load_space(_write(tmp_path, steered)).objectives][-1] == "size_ratio"
    text = SMALL_SPACE.replace('baseline = "tesamap"', 'baseline = ""') + \
        '\n[[objectives]]\nname = "size_ratio"\n'
    with pytest.raises(SpaceError, match="size_ratio needs a baseline"):
        load_space(_write(tmp_path, text))


def test_unreadable_space(tmp_path: Path) -> None:
    with pytest.raises(SpaceError, match="cannot read"):
        load_space(tmp_path / "missing.toml")
