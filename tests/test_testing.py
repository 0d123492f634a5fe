"""evsmap.testing: a missing piece skips on a developer's machine and fails in CI; and the
data root's order of precedence."""

from __future__ import annotations

import pytest

from evsmap import paths, testing


@pytest.mark.parametrize("value", ["true", "1", "TRUE", "yes"])
def test_missing_fails_in_ci(monkeypatch, value):
    monkeypatch.setenv("CI", value)
    with pytest.raises(pytest.fail.Exception, match="CI=true: a missing piece fails"):
        testing.missing("sample 'x' not found")


@pytest.mark.parametrize("value", [None, "", "false", "0"])
def test_missing_skips_elsewhere(monkeypatch, value):
    if value is None:
        monkeypatch.delenv("CI", raising=False)
    else:
        monkeypatch.setenv("CI", value)
    with pytest.raises(pytest.skip.Exception, match="sample 'x' not found"):
        testing.missing("sample 'x' not found")


def test_require_sample_names_the_fetch_command(monkeypatch, tmp_path):
    monkeypatch.delenv("CI", raising=False)
    monkeypatch.setenv("EVSMAP_DATA_ROOT", str(tmp_path))
    with pytest.raises(pytest.skip.Exception) as info:
        testing.require_sample("sevenscenes-100")
    assert "`evsmap datasets fetch sevenscenes-100`" in str(info.value)
    assert str(tmp_path / "sevenscenes_100") in str(info.value)
    (tmp_path / "sevenscenes_100").mkdir()
    assert testing.require_sample("sevenscenes-100") == tmp_path / "sevenscenes_100"


def test_require_module(monkeypatch):
    monkeypatch.delenv("CI", raising=False)
    assert testing.require_module("json").dumps([]) == "[]"
    with pytest.raises(pytest.skip.Exception, match="no_such_module_evsmap cannot be imported"):
        testing.require_module("no_such_module_evsmap")


def test_data_root_precedence(monkeypatch, tmp_path):
    monkeypatch.setenv("EVSMAP_DATA_ROOT", str(tmp_path / "mine"))
    assert paths.default_data_root() == tmp_path / "mine"
    monkeypatch.delenv("EVSMAP_DATA_ROOT")
    monkeypatch.setattr(paths, "shared_data_dir", lambda: tmp_path / "shared" / "data")
    assert paths.default_data_root() == tmp_path / "shared" / "data"
    monkeypatch.setattr(paths, "shared_data_dir", lambda: None)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert paths.default_data_root() == tmp_path / "cache" / "evsmap" / "data"
