"""docs/plugins.md, run: its code blocks become an installed third-party package (modules on
``sys.path`` and a ``*.dist-info/entry_points.txt``), found through the ``evsmap.plugins`` entry
point, and ``evsmap map`` maps the synthetic sequence with the new updater and segmenter."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from evsmap import registry
from evsmap.cli.main import main
from evsmap.mapping.node_type import NODE_TYPES
from evsmap.mapping.octree_io import read_ot
from evsmap.registry import SEGMENTERS, UPDATERS

DOC = Path(__file__).resolve().parents[1] / "docs" / "plugins.md"
BLOCK = re.compile(r"^```\w+ file=(\S+)\n(.*?)^```$", re.S | re.M)


def doc_files() -> dict[str, str]:
    """The page's code blocks marked ``file=NAME``, by name."""
    return {name: body for name, body in BLOCK.findall(DOC.read_text(encoding="utf-8"))}


def entry_points_txt(toml: str) -> str:
    """The ``[project.entry-points."evsmap.plugins"]`` table as ``entry_points.txt``."""
    import tomllib

    table = tomllib.loads(toml)["project"]["entry-points"]["evsmap.plugins"]
    return "[evsmap.plugins]\n" + "".join(f"{k} = {v}\n" for k, v in table.items())


@pytest.fixture
def plugin_package(tmp_path, monkeypatch):
    """The doc's package, installed into a folder on ``sys.path``; removed again afterwards."""
    files = doc_files()
    modules = sorted(n for n in files if n.endswith(".py"))
    site = tmp_path / "site"
    site.mkdir()
    for name in modules:
        (site / name).write_text(files[name], encoding="utf-8")
    info = site / "evsmap_plugin_example-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: evsmap-plugin-example\n"
                                   "Version: 0.1\n", encoding="utf-8")
    (info / "entry_points.txt").write_text(entry_points_txt(files["pyproject-entry-points"]),
                                           encoding="utf-8")
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setattr(registry, "_loaded", False)  # load the entry points again
    yield modules
    for reg, name in ((UPDATERS, "max-confidence"), (SEGMENTERS, "row-bands")):
        if name in reg.names():
            reg.unregister(name)
    if "MaxConfidenceOcTree" in NODE_TYPES:
        NODE_TYPES.remove("MaxConfidenceOcTree")
    for name in modules:
        sys.modules.pop(name[:-3], None)


def test_doc_package_is_one_module_and_one_entry_point_each():
    files = doc_files()
    assert sorted(files) == ["maxconf_map.py", "pyproject-entry-points", "row_bands.py",
                             "systems.toml"]
    entries = entry_points_txt(files["pyproject-entry-points"]).splitlines()[1:]
    assert entries == ["maxconf_map = maxconf_map", "row_bands = row_bands"]


def test_entry_point_plugins_map_the_synthetic_sequence(plugin_package, tmp_path, capsys):
    assert "max-confidence" in UPDATERS.names() and "row-bands" in SEGMENTERS.names()
    out = tmp_path / "m.ot"
    code = main(["map", "synthetic", "--updater", "max-confidence", "--segmenter", "row-bands",
                 "-s", "first_class=10", "--frames", "3", "--resolution", "0.1",
                 "-r", "width=160", "-r", "height=120", "--out", str(out), "--json"])
    record = json.loads(capsys.readouterr().out)
    assert code == 0
    assert record["updater"] == "max-confidence" and record["segmenter"] == "row-bands"
    assert record["nodes"] > 100 and record["map_bytes"] == out.stat().st_size
    # the file is read by its id through the node-type registry, no layout passed in
    kind, resolution, tree = read_ot(out)
    assert (kind, resolution) == ("MaxConfidenceOcTree", 0.1)
    assert tree.payload.dtype.names == ("label", "conf")
    # every label comes from the new segmenter: bands 10..13 (default 4 bands), conf 0.5
    labels = tree.payload["label"][tree.child_mask == 0]
    seen = set(np.unique(labels[labels >= 0]).tolist())
    assert seen and seen <= {10, 11, 12, 13}
    assert set(np.unique(tree.payload["conf"][tree.payload["label"] >= 0])) == {0.5}
    # the full file reloads into the same map, and its occupied voxels carry those labels
    again = UPDATERS.create("max-confidence", resolution=0.1).restore(out)
    codes, occupied = again.occupied_labels()
    assert codes.size and set(np.unique(occupied).tolist()) <= {-1, 10, 11, 12, 13}
    assert (occupied >= 10).sum() > 0.9 * codes.size
    assert again.stats().nodes == record["nodes"]
    again.write(tmp_path / "again.ot")
    assert (tmp_path / "again.ot").read_bytes() == out.read_bytes()


def test_plugins_registered_the_old_way_get_what_they_take_from_their_signature(
        plugin_package, capsys, tmp_path):
    """The doc's factories declare no ``takes=``: the registry derives it from their signatures
    when they register, and the callers read it (``--weights`` refused for a non-network)."""
    from evsmap.registry import Takes

    updater, segmenter = UPDATERS.get("max-confidence"), SEGMENTERS.get("row-bands")
    assert updater.takes == Takes(resolution=True) and segmenter.takes == Takes()
    assert updater.defaults() == {"resolution": 0.05, "max_range": 5.0, "discretize": True}
    assert list(segmenter.options) == ["bands", "first_class", "num_classes"]
    code = main(["predict", "row-bands", "synthetic", "--weights", str(tmp_path / "w.pt"),
                 "--out", str(tmp_path / "never")])
    err = capsys.readouterr().err
    assert code == 2 and "row-bands is not a network and takes no weights" in err, err
    assert not (tmp_path / "never").exists()


def test_the_doc_systems_map_beside_table_iv_in_the_runner(plugin_package, tmp_path):
    """``evsmap reproduce --systems``: the doc's system becomes a mapping run of the plan, and
    the runner's mapping cell maps it with the plug-in segmenter's own labels (not a network:
    no weights, no oracle)."""
    import tomllib
    from concurrent.futures import ThreadPoolExecutor

    from evsmap.runner import matrix
    from evsmap.runner.context import RunContext
    from evsmap.runner.systems import parse_systems

    systems = parse_systems(tomllib.loads(doc_files()["systems.toml"]), source="systems.toml")
    assert [(s.id, s.segmenter.spec, s.segmenter_is_network) for s in systems] == [
        ("maxconf", "row-bands(first_class=10)", False)]
    empty = tmp_path / "data"
    empty.mkdir()
    ctx = RunContext.create(tmp_path / "run", data_root=empty, quick=True)
    full = matrix.plan(ctx, ["table4"], systems)
    mine = [r for r in full.runs if r.row == "maxconf"]
    assert len(mine) == len(full.sequences) == 1 and mine[0].own_labels
    assert mine[0].key == f"extra/mapping/maxconf/synthetic@{ctx.resolution:g}m"
    [record] = matrix.run_matrix(ctx, matrix.Plan(specs=[], runs=mine, sequences=["synthetic"]),
                                 pool=lambda n: ThreadPoolExecutor(1),
                                 fresh=lambda: ThreadPoolExecutor(1))  # in this process
    assert record.status == "ok", record.error
    assert record.values["map_bytes"] > 0 and record.values["nodes"] > 100
    assert any("labels from row-bands(first_class=10)" in n for n in record.notes)
    segment_ms, update_ms = record.details["segment_ms"], record.details["update_ms"]
    if "segment_timing" in record.details:  # labels from the shared cache: timed on their own,
        assert len(segment_ms) >= 3 and len(update_ms) > 0  # under the timing policy
    else:  # segmented in the mapping loop: one time a frame
        assert len(segment_ms) == len(update_ms) > 0
    with np.load(tmp_path / "run" / "artifacts" / "map-maxconf-synthetic.npz") as saved:
        labels = saved["labels"]
    assert set(np.unique(labels[labels >= 0]).tolist()) <= {10, 11, 12, 13}


@pytest.mark.parametrize("text, message", [
    ('[[systems]]\nid = "orgbmap"\nupdater = { name = "orgb" }\n', "the id is taken"),
    ('[[systems]]\nid = "x"\nupdater = { name = "no-such-updater" }\n', "no-such-updater"),
    ('[[systems]]\nid = "x"\nupdater = { name = "orgb", options = { colour = 1 } }\n',
     "colour"),
    ('[[systems]]\nid = "x"\nupdater = { name = "orgb" }\nsegmentr = { name = "oracle" }\n',
     "segmentr"),
    ('[[systems]]\nid = "Bad Id"\nupdater = { name = "orgb" }\n', "an id is lower-case"),
    ("[[systems]\n", "not valid TOML"),
])
def test_a_bad_systems_file_is_one_line_and_nothing_is_written(capsys, tmp_path, text, message):
    path = tmp_path / "systems.toml"
    path.write_text(text, encoding="utf-8")
    out = tmp_path / "run"
    code = main(["reproduce", "--quick", "--tables", "IV", "--systems", str(path), "--out",
                 str(out)])
    err = capsys.readouterr().err
    assert code == 2 and message in err and str(path) in err, err
    assert len(err.strip().splitlines()) == 1 and not out.exists()
