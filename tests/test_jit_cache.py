"""Compiled kernels follow the code: numba's cache of evsmap's kernels is keyed by every module a
kernel's file imports (evsmap.mapping.jit_cache), and ``evsmap cache clear kernels`` reaches it.

The end-to-end tests run copies of evsmap and baselines in fresh interpreters, so that editing a
module and compiling never touch this checkout's sources or compiled files."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from evsmap.mapping import jit_cache

REPO = Path(__file__).resolve().parents[1]

CALLEE = """from numba import njit

SCALE = {scale}


@njit(cache=True)
def scale(x):
    return x * SCALE
"""

CALLER = """from numba import njit

from {package}.callee import scale


@njit(cache=True)
def scaled_plus_one(x):
    return scale(x) + 1
"""

PROBE = """import json, sys
import evsmap  # noqa: F401 - what every evsmap process imports first
from evsmap._jit_probe.caller import scaled_plus_one as inside
from plain_probe.caller import scaled_plus_one as outside
values = {"inside": inside(1), "outside": outside(1)}
print(json.dumps({"values": values, "hits": sum(inside.stats.cache_hits.values()),
                  "where": inside._cache._cache_path}))
"""


def _copy_sources(tmp_path: Path) -> Path:
    """evsmap and baselines (the plug-in the entry point names) copied under ``tmp_path/src``,
    without compiled files."""
    src = tmp_path / "src"
    for package in ("evsmap", "baselines"):
        shutil.copytree(REPO / package, src / package,
                        ignore=shutil.ignore_patterns("__pycache__"))
    return src


def _run(src: Path, tmp_path: Path, *args: str, **env: str) -> subprocess.CompletedProcess:
    environ = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CACHE")}
    environ.update(PYTHONPATH=str(src), EVSMAP_CACHE_DIR=str(tmp_path / "cache"), **env)
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, env=environ,
                          cwd=tmp_path, timeout=300)


def _write_probe_packages(src: Path, scale: int) -> None:
    """The same two modules (a jitted callee, a cached jitted caller) inside evsmap's package and
    in a package of their own."""
    for package, folder in (("evsmap._jit_probe", src / "evsmap" / "_jit_probe"),
                            ("plain_probe", src / "plain_probe")):
        folder.mkdir(exist_ok=True)
        (folder / "__init__.py").write_text("")
        (folder / "callee.py").write_text(CALLEE.format(scale=scale))
        (folder / "caller.py").write_text(CALLER.format(package=package))


def _probe(src: Path, tmp_path: Path, **env: str) -> dict:
    proc = _run(src, tmp_path, "-c", PROBE, **env)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


@pytest.mark.slow
@pytest.mark.parametrize("place", ["beside the sources", "NUMBA_CACHE_DIR", "read-only sources"])
def test_an_edited_callee_recompiles_its_cached_caller(tmp_path, place):
    src = _copy_sources(tmp_path)
    _write_probe_packages(src, scale=2)
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "numba")} if place == "NUMBA_CACHE_DIR" else {}
    if place == "read-only sources":  # a file where the __pycache__ folder would be
        (src / "evsmap" / "_jit_probe" / "__pycache__").write_text("")
    expected_place = {"beside the sources": src / "evsmap" / "_jit_probe" / "__pycache__",
                      "NUMBA_CACHE_DIR": tmp_path / "numba",
                      "read-only sources": tmp_path / "cache" / "kernels"}[place]

    first = _probe(src, tmp_path, **env)
    assert first["values"] == {"inside": 3, "outside": 3} and first["hits"] == 0
    assert Path(first["where"]).is_relative_to(expected_place)
    assert _probe(src, tmp_path, **env)["hits"] == 1  # still cached when nothing changed

    _write_probe_packages(src, scale=5)  # only the callee's module changes
    edited = _probe(src, tmp_path, **env)
    assert edited["values"]["outside"] == 3  # numba's own cache: the stale caller
    assert edited["values"]["inside"] == 6 and edited["hits"] == 0  # evsmap's: recompiled
    assert _probe(src, tmp_path, **env) == {**edited, "hits": 1}


KERNEL_LOCATORS = """import importlib, json, sys
from pathlib import Path
from numba.core.dispatcher import Dispatcher
from evsmap.mapping import jit_cache
report = {}
for name in sys.argv[1:]:
    module = importlib.import_module(name)
    for attr, value in vars(module).items():
        if isinstance(value, Dispatcher) and value.py_func.__module__ == name:
            locator = value._cache._impl.locator
            stamp_ok = locator.get_source_stamp() == jit_cache.closure_digest(module.__file__)
            report[f"{name}.{attr}"] = [type(locator).__name__, stamp_ok]
print(json.dumps(report))
"""


def _kernel_modules() -> list[str]:
    """Every evsmap and baselines module holding a cached numba kernel."""
    found = []
    for package in ("evsmap", "baselines"):
        for path in sorted((REPO / package).rglob("*.py")):
            text = path.read_text()
            if "njit(cache=True" in text or '"cache": True' in text:
                found.append(".".join(path.relative_to(REPO).with_suffix("").parts))
    return found


def test_the_kernel_modules_are_found():
    modules = _kernel_modules()
    assert {"evsmap.mapping.voxel_grid", "evsmap.mapping.stdsort", "evsmap.mapping.kernels",
            "baselines.semantic_slam_kernels", "evsmap.synth.shading"} <= set(modules)


@pytest.mark.slow
@pytest.mark.parametrize("first", ["evsmap.mapping.stdsort", "numba", "baselines"])
def test_every_kernel_is_keyed_by_its_code_whatever_is_imported_first(first):
    # a fresh interpreter: `first` alone, then every kernel module (decorated, not compiled)
    modules = _kernel_modules()
    code = f"import {first}\n" + KERNEL_LOCATORS
    proc = subprocess.run([sys.executable, "-c", code, *modules], capture_output=True,
                          text=True, timeout=300, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert {name.rpartition(".")[0] for name in report} == set(modules)
    assert {tuple(v) for v in report.values()} == {("KernelLocator", True)}, report


def test_a_kernel_stamp_covers_the_modules_it_takes_functions_and_constants_from():
    def names(path: str) -> set[str]:
        return {p.relative_to(REPO).as_posix() for p in jit_cache.closure(REPO / path)}

    assert names("evsmap/mapping/voxel_grid.py") == {"evsmap/mapping/voxel_grid.py",
                                                    "evsmap/mapping/stdsort.py"}
    assert "evsmap/mapping/kernels.py" in names("evsmap/mapping/mcb_kernel.py")  # blocks
    assert "evsmap/mapping/generator.py" in names("evsmap/mapping/ssmi_kernel.py")  # WHITE
    slam = names("baselines/semantic_slam_kernels.py")
    assert {"evsmap/mapping/voxel_grid.py", "evsmap/mapping/stdsort.py"} <= slam
    assert "baselines/semantic_slam_fusion.py" in names("baselines/classic_semantic_kernels.py")
    assert "evsmap/cli/main.py" not in slam  # an unrelated edit recompiles nothing


def test_a_stamp_changes_with_an_imported_module(tmp_path):
    src = _copy_sources(tmp_path)
    code = ("from evsmap.mapping import jit_cache; import sys; "
            "print(jit_cache.closure_digest(sys.argv[1]))")
    voxel_grid = src / "evsmap" / "mapping" / "voxel_grid.py"

    def stamp() -> str:
        proc = _run(src, tmp_path, "-c", code, str(voxel_grid))
        assert proc.returncode == 0, proc.stderr
        return proc.stdout.strip()

    before = stamp()
    assert before == stamp()
    (src / "evsmap" / "cli" / "main.py").write_text("# unrelated\n", encoding="utf-8")
    assert stamp() == before
    stdsort = src / "evsmap" / "mapping" / "stdsort.py"
    stdsort.write_text(stdsort.read_text() + "\n# edited\n")
    assert stamp() != before


def test_cache_clear_kernels_removes_the_compiled_kernels_only(tmp_path):
    src = _copy_sources(tmp_path)
    compiled = [src / "evsmap" / "mapping" / "__pycache__" / "voxel_grid.voxel_grid-49.py311.nbi",
                src / "evsmap" / "mapping" / "__pycache__" / "voxel_grid.voxel_grid-49.py311.1.nbc",
                src / "baselines" / "__pycache__" / "semantic_slam_kernels.f-1.py311.nbi",
                tmp_path / "cache" / "kernels" / "mapping_0123" / "stdsort._swap-29.py311.nbi"]
    kept = [src / "evsmap" / "mapping" / "__pycache__" / "voxel_grid.cpython-311.pyc",
            tmp_path / "cache" / "onnx" / "a.onnx"]
    for path in compiled + kept:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"x" * 1000)

    info = _run(src, tmp_path, "-m", "evsmap", "cache", "info", "--json")
    assert info.returncode == 0, info.stderr
    kernels = json.loads(info.stdout)["kinds"]["kernels"]
    assert kernels["files"] == 4 and kernels["bytes"] == 4000
    assert kernels["beside_sources"] == {"files": 3, "bytes": 3000}

    cleared = _run(src, tmp_path, "-m", "evsmap", "cache", "clear", "kernels")
    assert cleared.returncode == 0, cleared.stderr
    assert [p for p in compiled if p.exists()] == []
    assert all(p.exists() for p in kept)


def test_a_numba_without_the_expected_locators_warns_and_evsmap_still_runs():
    code = ("import warnings\nimport numba.core.caching as caching\ndel caching.CacheImpl\n"
            "with warnings.catch_warnings(record=True) as caught:\n"
            "    warnings.simplefilter('always')\n"
            "    from evsmap.mapping import jit_cache, stdsort\n"
            "print(jit_cache.KernelLocator, [str(w.message) for w in caught])")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("None ") and "evsmap cache clear kernels" in proc.stdout
