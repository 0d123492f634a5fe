"""``evsmap reproduce --systems``: the file's checks, and how a user's system maps."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import pytest

from evsmap.errors import EvsmapError
from evsmap.runner import matrix
from evsmap.runner.context import RunContext
from evsmap.runner.systems import parse_systems, systems_from_records


def _systems(*items, taken=frozenset()):
    return parse_systems({"systems": list(items)}, source="mine.toml", taken=set(taken))


def test_a_system_names_registered_plugins_and_knows_a_network():
    oracle, net = _systems(
        {"id": "a", "updater": {"name": "multiclass-bayes"}, "segmenter": {"name": "oracle"}},
        {"id": "b", "label": "B", "updater": {"name": "orgb"},
         "segmenter": {"name": "feagnet-v1", "options": {"input_size": [64, 96]}}})
    assert (oracle.label, oracle.segmenter_is_network) == ("a", False)
    assert (net.label, net.segmenter_is_network) == ("B", True)
    # what run.json stores reads back to the same systems (--resume)
    again = systems_from_records([s.as_dict() for s in (oracle, net)], source="run.json")
    assert again == [oracle, net]


@pytest.mark.parametrize("items, message", [
    ([], "systems: List should have at least 1 item"),
    ([{"id": "a", "updater": {"name": "orgb"}}] * 2, "the id is taken (an earlier system)"),
    ([{"id": "evsmap", "updater": {"name": "orgb"}}], "the id is taken (a Table IV row)"),
    ([{"id": "a", "updater": {"name": "orgb"}, "labels": 1}], "systems[0].labels: Extra inputs"),
    ([{"id": "a"}], "systems[0].updater: Field required"),
])
def test_bad_systems_are_one_line_naming_the_file(items, message):
    with pytest.raises(EvsmapError) as err:
        _systems(*items, taken={"evsmap"})
    text = str(err.value)
    assert text.startswith("mine.toml: ") and message in text and "\n" not in text


def test_the_oracle_on_a_sequence_without_labels_is_not_applicable(tmp_path, tum_dir):
    [system] = _systems({"id": "mine", "updater": {"name": "multiclass-bayes"},
                         "segmenter": {"name": "oracle"}})
    ctx = RunContext.create(tmp_path / "run", data_root=tum_dir.parent, quick=True)
    assert ctx.dataset_path("tum") is not None
    plan = matrix.plan(ctx, ["table4"], [system])
    runs = [r for r in plan.runs if r.row == "mine" and r.sequence == "tum"
            and r.resolution == ctx.resolution]
    assert len(runs) == 1 and runs[0].own_labels
    [record] = matrix.run_matrix(ctx, matrix.Plan(specs=[], runs=runs, sequences=["tum"]),
                                 pool=lambda n: ThreadPoolExecutor(1),
                                 fresh=lambda: ThreadPoolExecutor(1))
    assert record.status == "na" and record.needs == ["labels:tum"]
    assert "oracle reads ground-truth labels and tum has none" in record.reason
