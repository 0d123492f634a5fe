"""Fuzz targets: evsmap's own text files a user can hand it - a run folder's ``run.json`` and
``records/*.json`` (:mod:`evsmap.runner.records`, :func:`evsmap.report.build.read_run` /
``read_records``, ``evsmap report RUN``), the gate's baseline JSON, and the TOML files: training
recipes, the paper tables file, the ``--systems`` file.

Samples are real: a run folder written by the report tests' fixture (no measuring), the shipped
baseline, recipes and tables, the systems example of ``docs/plugins.md``; then line and byte
mutations, and hypothesis-generated documents (wrong types, unknown keys, NaN, huge numbers,
deep nesting). The property is :func:`tests.fuzz.harness.check_file`'s: one line naming the
file, no traceback, no hang, bounded memory; the CLI exits 2 with one line.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.fuzz.harness import check_cli, check_file, mutated_bytes, text_lines, write_variant

ROOT = Path(__file__).resolve().parents[2]

# JSON / TOML values: scalars of every kind, odd numbers, nesting
_ODD_NUMBERS = st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e308, 5e-324, -0.0,
                                10**30, -(10**30), 2**63, 2**64, -(2**63) - 1])
_SCALAR = st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70), _ODD_NUMBERS,
                    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=10))
_VALUE = st.recursive(_SCALAR, lambda inner: st.one_of(
    st.lists(inner, max_size=3), st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=10)


def _deep(depth: int, kind: str) -> str:
    return ("[" * depth + "]" * depth) if kind == "list" else ('{"a":' * depth + "1"
                                                               + "}" * depth)


def _json_text(value: Any) -> str:
    return json.dumps(value, indent=1, allow_nan=True)


def _slow_examples(fraction: int) -> int:
    """A fraction of the profile's examples for a target whose example takes a second."""
    return max(3, settings.default.max_examples // fraction)


# ------------------------------------------------------------------------------ run folders
@pytest.fixture(scope="module")
def run_template(tmp_path_factory) -> Path:
    from tests.report.conftest import make_run

    return make_run(tmp_path_factory.mktemp("template") / "run", artifacts=False)


def _fresh_run(template: Path, folder: Path) -> Path:
    run = folder / "run"
    if run.exists():
        shutil.rmtree(run)
    shutil.copytree(template, run)
    return run


def _record_files(run: Path) -> list[Path]:
    return sorted((run / "records").glob("*.json"))


def _read_all(run: Path) -> None:
    from evsmap.report.build import read_records, read_run
    from evsmap.runner.records import RecordStore

    read_run(run)
    for rec in read_records(run):
        RecordStore(run).get(rec.key)
    RecordStore(run).all()


def test_fuzz_record_files(tmp_path_factory, run_template):
    """One record file mutated, as lines or bytes; read through read_records and RecordStore."""
    folder = tmp_path_factory.mktemp("rec")
    files = _record_files(run_template)

    @given(st.integers(0, len(files) - 1), st.data())
    def inner(i, data):
        run = _fresh_run(run_template, folder)
        target = _record_files(run)[i]
        raw = target.read_bytes()
        new = data.draw(st.one_of(text_lines(raw.decode().splitlines()), mutated_bytes(raw)))
        write_variant(target, new)
        check_file("records/record-file", lambda: _read_all(run), target)

    inner()


@st.composite
def generated_record(draw: st.DrawFn, real: dict[str, Any]) -> str:
    """A real record's fields replaced by generated values, removed, or joined by unknown
    ones; or another JSON document altogether (deep nesting, a list, a number)."""
    kind = draw(st.sampled_from(["fields", "fields", "document", "deep"]))
    if kind == "deep":
        return _deep(draw(st.sampled_from([100, 5000, 200_000])),
                     draw(st.sampled_from(["list", "dict"])))
    if kind == "document":
        return _json_text(draw(_VALUE))
    rec = dict(real)
    for _ in range(draw(st.integers(1, 4))):
        key = draw(st.sampled_from(sorted(rec) + ["unknown", "values"]))
        how = draw(st.sampled_from(["replace", "drop", "value"]))
        if how == "drop":
            rec.pop(key, None)
        elif how == "value":
            rec["values"] = {draw(st.text(max_size=5)): draw(_VALUE)}
        else:
            rec[key] = draw(_VALUE)
    return _json_text(rec)


def test_fuzz_records_generated(tmp_path_factory, run_template):
    folder = tmp_path_factory.mktemp("recgen")
    files = _record_files(run_template)
    reals = [json.loads(p.read_text()) for p in files]

    @given(st.integers(0, len(files) - 1).flatmap(
        lambda i: st.tuples(st.just(i), generated_record(reals[i]))))
    def inner(pick):
        i, text = pick
        run = _fresh_run(run_template, folder)
        target = write_variant(_record_files(run)[i], text)
        check_file("records/record-generated", lambda: _read_all(run), target)

    inner()


@st.composite
def generated_run(draw: st.DrawFn, real: dict[str, Any]) -> str:
    if draw(st.integers(0, 5)) == 0:
        return draw(st.one_of(st.just(_deep(100_000, "list")), _VALUE.map(_json_text)))
    run = dict(real)
    for _ in range(draw(st.integers(1, 4))):
        key = draw(st.sampled_from(sorted(run) + ["skipped", "systems", "unknown"]))
        if draw(st.booleans()):
            run.pop(key, None)
        else:
            run[key] = draw(_VALUE)
    return _json_text(run)


def test_fuzz_run_json(tmp_path_factory, run_template):
    folder = tmp_path_factory.mktemp("runjson")
    raw = (run_template / "run.json").read_bytes()
    real = json.loads(raw)

    @given(st.one_of(text_lines(raw.decode().splitlines()), mutated_bytes(raw),
                     generated_run(real)))
    def inner(new):
        run = _fresh_run(run_template, folder)
        target = write_variant(run / "run.json", new)
        check_file("records/run-json", lambda: _read_all(run), target)

    inner()


def test_fuzz_report_cli(tmp_path_factory, run_template, capsys):
    """``evsmap report RUN`` on a run folder with run.json or one record mutated (a second an
    example: fewer examples)."""
    folder = tmp_path_factory.mktemp("report")
    files = [p.name for p in _record_files(run_template)]
    raw_run = json.loads((run_template / "run.json").read_text())
    reals = {name: json.loads((run_template / "records" / name).read_text()) for name in files}

    @settings(max_examples=_slow_examples(3))
    @given(st.sampled_from(["run.json", *files]).flatmap(
        lambda name: st.tuples(st.just(name), generated_run(raw_run) if name == "run.json"
                               else generated_record(reals[name]))))
    def inner(pick):
        name, text = pick
        run = _fresh_run(run_template, folder)
        target = run / name if name == "run.json" else run / "records" / name
        write_variant(target, text)
        check_cli("records/report-cli", ["report", str(run)], (name,), capsys)

    inner()


def test_report_cli_on_broken_folders(tmp_path, run_template, capsys):
    """No run.json, a folder where run.json should be, a record that is a folder, no folder."""
    cases = []
    run = _fresh_run(run_template, tmp_path / "a")
    (run / "run.json").unlink()
    cases.append((run, "run.json"))
    run = _fresh_run(run_template, tmp_path / "b")
    (run / "run.json").unlink()
    (run / "run.json").mkdir()
    cases.append((run, "run.json"))
    run = _fresh_run(run_template, tmp_path / "c")
    (run / "records" / "zz-folder.json").mkdir()
    cases.append((run, "zz-folder.json"))
    run = _fresh_run(run_template, tmp_path / "d")
    (run / "records" / "empty.json").write_bytes(b"")
    cases.append((run, "empty.json"))
    cases.append((tmp_path / "missing", "missing"))
    for run, name in cases:
        check_cli("records/report-cli-folders", ["report", str(run)], (name,), capsys)


# ------------------------------------------------------------------------------ gate baseline
@st.composite
def generated_baseline(draw: st.DrawFn, real: dict[str, Any]) -> str:
    data = json.loads(json.dumps(real))
    (kind,) = list(data["kinds"])[:1]
    names = sorted(data["kinds"][kind]["workloads"])
    for _ in range(draw(st.integers(1, 4))):
        where = draw(st.sampled_from(["workload", "field", "kind", "top", "document"]))
        entry = data.get("kinds", {}).get(kind) if isinstance(data.get("kinds"), dict) else None
        if where == "document":
            return draw(st.one_of(_VALUE.map(_json_text), st.just(_deep(50_000, "dict"))))
        if where == "top":
            data[draw(st.sampled_from(["kinds", "format", "workloads"]))] = draw(_VALUE)
        elif not isinstance(entry, dict):
            continue
        elif where == "kind":
            entry[draw(st.sampled_from(["workloads", "machine", "settings", "commit"]))] = \
                draw(_VALUE)
        elif where == "workload" and isinstance(entry.get("workloads"), dict):
            entry["workloads"][draw(st.sampled_from(names))] = draw(_VALUE)
        elif isinstance(entry.get("workloads"), dict):
            figures = entry["workloads"].get(draw(st.sampled_from(names)))
            if isinstance(figures, dict):
                figures[draw(st.sampled_from(["time_ratio", "peak_rss_bytes", "frames"]))] = \
                    draw(_VALUE if draw(st.booleans()) else _SCALAR)
    return _json_text(data)


def test_fuzz_gate_baseline(tmp_path_factory):
    from evsmap.gate.baseline import read_baseline

    folder = tmp_path_factory.mktemp("gate")
    raw = (ROOT / "benchmarks" / "baseline.json").read_bytes()
    real = json.loads(raw)

    @given(st.one_of(mutated_bytes(raw), text_lines(raw.decode().splitlines()[:80]),
                     generated_baseline(real)))
    def inner(new):
        path = write_variant(folder / "baseline.json", new)
        check_file("gate/baseline", lambda: read_baseline(path), path)

    inner()


# ------------------------------------------------------------------------------ TOML writing
def _toml_key(key: str) -> str:
    return json.dumps(key)


def _toml_value(value: Any) -> str:
    """A TOML value (inline tables for dicts; NaN / Inf as TOML spells them; None as an empty
    string, which TOML lacks)."""
    if value is None:
        return '""'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_toml_key(str(k))} = {_toml_value(v)}"
                               for k, v in value.items()) + "}"
    return json.dumps(str(value))


def _toml_flat(data: dict[str, Any]) -> str:
    return "\n".join(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in data.items()) + "\n"


# ------------------------------------------------------------------------------ recipes
RECIPES = sorted((ROOT / "evsmap" / "train" / "recipes").glob("*.toml"))
_RECIPE_ODD = st.one_of(_SCALAR, st.sampled_from([[0, 0], [-1, 5], [1e9, 1e9], [1.5, 0.5],
                                                  [math.nan, 1.0], "input", "paper",
                                                  "../paper.toml", [], {}]))


@st.composite
def generated_recipe(draw: st.DrawFn) -> str:
    from evsmap.train.recipe import load_recipe

    data = load_recipe(draw(st.sampled_from(["paper", "synth-proxy"]))).as_dict()
    for _ in range(draw(st.integers(1, 4))):
        key = draw(st.sampled_from(sorted(data) + ["base", "unknown", "crop", "scale"]))
        how = draw(st.sampled_from(["replace", "replace", "drop", "table"]))
        if how == "drop":
            data.pop(key, None)
        elif how == "table":
            data[key] = {"x": 1}
        else:
            data[key] = draw(_RECIPE_ODD)
    return _toml_flat(data)


def test_fuzz_recipe_files(tmp_path_factory):
    from evsmap.train.recipe import load_recipe

    folder = tmp_path_factory.mktemp("recipe")
    texts = [p.read_text() for p in RECIPES]

    @given(st.one_of(
        st.sampled_from(texts).flatmap(lambda t: text_lines(t.splitlines())),
        st.sampled_from(texts).flatmap(lambda t: mutated_bytes(t.encode())),
        generated_recipe()))
    def inner(new):
        path = write_variant(folder / "my-recipe.toml", new)
        check_file("toml/recipe", lambda: load_recipe(path), path)

    inner()


def test_recipe_base_chains(tmp_path):
    """A recipe whose base is missing, unreadable, a loop, itself, or not TOML: the message
    names the user's file."""
    from evsmap.train.recipe import load_recipe

    (tmp_path / "loop-a.toml").write_text('base = "loop-b.toml"\n')
    (tmp_path / "loop-b.toml").write_text('base = "loop-a.toml"\n')
    (tmp_path / "garbage.toml").write_bytes(b"\xff\xfe = 1\n")
    (tmp_path / "folder.toml").mkdir()
    cases = {"self.toml": 'base = "self.toml"\n', "missing.toml": 'base = "nope.toml"\n',
             "bad-base.toml": 'base = "garbage.toml"\n', "dir-base.toml": 'base = "folder.toml"\n',
             "name-base.toml": 'base = "no-such-recipe"\n', "abs.toml": 'base = "/"\n',
             "num-base.toml": "base = 3\n", "loop.toml": 'base = "loop-a.toml"\n',
             "unknown.toml": 'base = "paper"\nnot_a_field = 1\n',
             "newline-base.toml": 'base = "a\\nb.toml"\n'}
    for name, text in cases.items():
        path = write_variant(tmp_path / name, text)
        check_file("toml/recipe-base", lambda p=path: load_recipe(p), path)


# ------------------------------------------------------------------------------ paper tables
TABLES = ROOT / "evsmap" / "tables" / "paper_tables.toml"


@st.composite
def generated_tables(draw: st.DrawFn, real: dict[str, Any]) -> dict[str, Any]:
    """The real tables with values replaced at random paths (wrong types, NaN, negative, deep
    lists), keys dropped or added."""
    data = json.loads(json.dumps(real))
    for _ in range(draw(st.integers(1, 4))):
        node: Any = data
        for _ in range(draw(st.integers(0, 5))):
            if isinstance(node, dict) and node:
                nxt = node[draw(st.sampled_from(sorted(node)))]
            elif isinstance(node, list) and node:
                nxt = node[draw(st.integers(0, len(node) - 1))]
            else:
                break
            if not isinstance(nxt, (dict, list)):
                break
            node = nxt
        how = draw(st.sampled_from(["replace", "drop", "add"]))
        if isinstance(node, dict) and node:
            key = draw(st.sampled_from(sorted(node)))
            if how == "drop":
                del node[key]
            elif how == "add":
                node[draw(st.text(min_size=1, max_size=8))] = draw(_VALUE)
            else:
                node[key] = draw(_VALUE)
        elif isinstance(node, list) and node:
            i = draw(st.integers(0, len(node) - 1))
            if how == "drop":
                del node[i]
            else:
                node[i] = draw(_VALUE)
    return data


def test_fuzz_tables_file(tmp_path_factory):
    from evsmap.tables.load import load_file

    folder = tmp_path_factory.mktemp("tables")
    raw = TABLES.read_bytes()

    @given(st.one_of(text_lines(raw.decode().splitlines()), mutated_bytes(raw)))
    def inner(new):
        path = write_variant(folder / "my_tables.toml", new)
        check_file("toml/tables-file", lambda: load_file(path), path)

    inner()


def test_fuzz_tables_generated(tmp_path_factory):
    import tomllib

    from evsmap.tables.load import parse_tables

    real = tomllib.loads(TABLES.read_text())

    @given(generated_tables(real))
    def inner(data):
        check_file("toml/tables-generated",
                   lambda: parse_tables(data, source="generated_tables.toml"), None,
                   names=("generated_tables.toml",))

    inner()


# ------------------------------------------------------------------------------ systems
def _docs_systems() -> str:
    text = (ROOT / "docs" / "plugins.md").read_text()
    start = text.index("```toml file=systems.toml\n") + len("```toml file=systems.toml\n")
    return text[start:text.index("```", start)]


@st.composite
def generated_systems(draw: st.DrawFn) -> str:
    plugin = st.fixed_dictionaries(
        {"name": st.one_of(st.sampled_from(["orgb", "multiclass-bayes", "octomap-cpp",
                                            "classic-semantic", "oracle", "feagnet-s", "nope",
                                            ""]), _SCALAR)},
        optional={"options": st.one_of(st.dictionaries(
            st.sampled_from(["resolution", "max_range", "theta", "clamp_min", "leaf_update",
                             "num_classes", "weights", "x"]), _SCALAR, max_size=3), _SCALAR),
            "extra": _SCALAR})
    system = st.fixed_dictionaries(
        {"id": st.one_of(st.sampled_from(["maxconf", "evsmap", "Bad Id", "a", ""]), _SCALAR)},
        optional={"label": _SCALAR, "updater": st.one_of(plugin, _SCALAR),
                  "segmenter": st.one_of(plugin, _SCALAR), "unknown": _SCALAR})
    systems = draw(st.lists(system, max_size=3))
    lines = []
    for s in systems:
        if draw(st.integers(0, 4)) == 0:  # a key of any text (newlines, quotes, control bytes)
            s = {**s, draw(st.text(min_size=1, max_size=6)): draw(_SCALAR)}
        lines.append("[[systems]]")
        lines += [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in s.items()]
    if draw(st.booleans()):
        lines.append(f"other = {_toml_value(draw(_SCALAR))}")
    return "\n".join(lines) + "\n"


def test_fuzz_systems_file(tmp_path_factory):
    from evsmap.runner.systems import load_systems

    folder = tmp_path_factory.mktemp("systems")
    example = _docs_systems()

    @given(st.one_of(text_lines(example.splitlines()), mutated_bytes(example.encode()),
                     generated_systems()))
    def inner(new):
        path = write_variant(folder / "my_systems.toml", new)
        check_file("toml/systems", lambda: load_systems(path, taken={"evsmap"}), path)

    inner()


def test_records_toml_regressions(tmp_path, run_template, capsys):
    """What the fuzzer found, kept as fixed cases: fields of the wrong JSON type that broke the
    report (a dict as a record's table, a list as its row, a number as run.json's skipped),
    keys holding line breaks (a record's unknown field, a systems key, a table id), a systems
    id with a trailing line break (``$`` matches before it)."""
    import tomllib

    from evsmap.runner.systems import load_systems
    from evsmap.tables.load import parse_tables

    name = _record_files(run_template)[0].name
    real = json.loads((run_template / "records" / name).read_text())
    for change in ({"table": {}}, {"row": []}, {"status": "odd", "key": "a\nb"}, {"x\ny": 1},
                   {"metrics": [1]}, {"seconds": "1"}, {"notes": None}):
        run = _fresh_run(run_template, tmp_path)
        target = write_variant(run / "records" / name, _json_text({**real, **change}))
        check_file("records/regressions", lambda r=run: _read_all(r), target)
        check_cli("records/regressions", ["report", str(run)], (name,), capsys)
    run = _fresh_run(run_template, tmp_path)
    raw_run = json.loads((run / "run.json").read_text())
    for change in ({"skipped": 3}, {"tables": [{}]}, {"available": [[1]]}):
        target = write_variant(run / "run.json", _json_text({**raw_run, **change}))
        check_cli("records/regressions", ["report", str(run)], ("run.json",), capsys)
    for text in ('[[systems]]\nid = "a"\nupdater = { name = "orgb" }\n"x\\ny" = 1\n',
                 '[[systems]]\nid = "a\\n"\nupdater = { name = "orgb" }\n'):
        path = write_variant(tmp_path / "systems.toml", text)
        check_file("records/regressions", lambda p=path: load_systems(p), path)
        with pytest.raises(Exception, match="systems"):
            load_systems(path)
    data = tomllib.loads(TABLES.read_text())
    data["tables"]["a\nb"] = {}
    check_file("records/regressions", lambda: parse_tables(data, source="tables.toml"), None,
               names=("tables.toml",))


def test_toml_huge_integers(tmp_path):
    """An integer too large for a float (recipe validation compared it as one) and one of more
    than 4300 digits (tomllib raises a bare ValueError for it, not TOMLDecodeError)."""
    from evsmap.runner.systems import load_systems
    from evsmap.tables.load import load_file
    from evsmap.train.recipe import load_recipe

    for digits in (400, 5000):
        big = "9" * digits
        for key in ("epochs", "lr", "scale", "crop"):
            value = f"[1, {big}]" if key in ("scale", "crop") else big
            path = write_variant(tmp_path / f"{key}-{digits}.toml",
                                 f'base = "paper"\n{key} = {value}\n')
            check_file("toml/huge-integers", lambda p=path: load_recipe(p), path)
        path = write_variant(tmp_path / f"systems-{digits}.toml",
                             f'[[systems]]\nid = "a"\nupdater = {{ name = "orgb", options = '
                             f'{{ max_range = {big} }} }}\n')
        check_file("toml/huge-integers", lambda p=path: load_systems(p), path)
        path = write_variant(tmp_path / f"tables-{digits}.toml",
                             TABLES.read_text().replace("schema_version = 1",
                                                        f"schema_version = {big}"))
        check_file("toml/huge-integers", lambda p=path: load_file(p), path)


def test_gate_baseline_refuses_nan_and_huge(tmp_path):
    """A NaN or infinite ratio (json reads NaN / Infinity) compared as nothing: refused, as an
    integer beyond the float range is."""
    from evsmap.errors import DataFormatError
    from evsmap.gate.baseline import read_baseline

    for value in ("NaN", "Infinity", "-1", "1" + "0" * 400, "true"):
        entry = '{"time_ratio": ' + value + ', "peak_rss_bytes": 1}'
        path = write_variant(tmp_path / "baseline.json",
                             '{"workloads": {"read/tum": ' + entry + "}}")
        check_file("gate/baseline-values", lambda p=path: read_baseline(p), path)
        with pytest.raises(DataFormatError, match="time_ratio"):
            read_baseline(path)


def test_toml_deep_nesting(tmp_path):
    """Arrays and inline tables nested thousands deep: tomllib recurses (RecursionError)."""
    from evsmap.runner.systems import load_systems
    from evsmap.tables.load import load_file
    from evsmap.train.recipe import load_recipe

    for depth in (400, 5000):
        for value in ("[" * depth + "]" * depth, "{a = " * depth + "1" + "}" * depth):
            text = f"lr = {value}\n"
            for name, read in (("recipe.toml", load_recipe), ("tables.toml", load_file),
                               ("systems.toml", load_systems)):
                path = write_variant(tmp_path / name, text)
                check_file("toml/deep-nesting", lambda r=read, p=path: r(p), path)
