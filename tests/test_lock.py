"""The dependency lock: pins read as pip reads them, differences from the environment reported."""

from __future__ import annotations

from evsmap import lock
from evsmap.testing import missing


def test_the_lock_pins_torch_and_every_direct_dependency():
    pins = lock.read_pins()
    assert pins["torch"] == "2.13.0"  # portable: both the CPU wheel and PyPI's build satisfy it
    import tomllib

    project = tomllib.loads((lock.REPO_ROOT / "pyproject.toml").read_text())["project"]
    wanted = list(project["dependencies"])
    for extra in project["optional-dependencies"].values():
        wanted += extra
    names = {lock.normalize(d.split(";")[0].split("[")[0].split("=")[0].split(">")[0].strip())
             for d in wanted}
    assert names - set(pins) == set()


def test_status_reports_a_version_outside_the_lock(tmp_path):
    fake = tmp_path / "constraints.txt"
    fake.write_text("# comment\nnumpy==0.0.1\n    # via x\nNot_Installed_Pkg==1.0\n"
                    "torch==2.13.0 ; sys_platform == 'linux'\n")
    status = lock.lock_status(fake)
    assert status["pins"] == 3
    assert set(status["differs"]) == {"numpy"}
    assert status["differs"]["numpy"][0] == "0.0.1"
    assert len(status["sha256"]) == 64


def test_the_installed_environment_matches_the_lock():
    # `nox -s tests` installs through the lock: in CI nothing may differ; elsewhere (a
    # hand-made environment) a difference skips, naming the packages
    status = lock.lock_status()
    assert status is not None
    if status["differs"]:
        missing(f"installed outside the lock: {status['differs']}")


def test_the_installed_version_is_the_first_on_the_path_and_vendored_copies_do_not_count(
        tmp_path, monkeypatch):
    class Dist:
        def __init__(self, name, version, where):
            self.metadata, self.version = {"Name": name}, version
            self._path = tmp_path / where / f"{name}-{version}.dist-info"

    dists = [Dist("zipp", "9.0", "site-packages/setuptools/_vendor"),
             Dist("Zipp", "4.1.2", "site-packages"), Dist("zipp", "1.0", "later/site-packages"),
             Dist("wheel", "0.46.3", "site-packages/setuptools/_vendor")]
    monkeypatch.setattr(lock.metadata, "distributions", lambda: iter(dists))
    assert lock.installed_versions() == {"zipp": "4.1.2"}


def test_importing_setuptools_does_not_change_what_counts_as_installed():
    import sys
    from importlib import metadata

    import setuptools  # noqa: F401  (it puts its _vendor folder on sys.path)

    installed = lock.installed_versions()
    for name in ("importlib-metadata", "platformdirs", "wheel", "zipp"):
        if name in installed:  # what Python resolves, not setuptools' vendored copy
            assert installed[name] == metadata.version(name), (name, sys.path)
