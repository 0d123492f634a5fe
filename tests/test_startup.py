"""The command line starts without the heavy libraries, and Open3D loads without a system libusb."""

from __future__ import annotations

import builtins
import json
import subprocess
import sys

import pytest

from evsmap import open3d_loader

HEAVY = ("torch", "open3d", "onnxruntime", "fvcore", "matplotlib", "numba", "scipy", "pydantic",
         "octomap", "pandas")

_PROBE = """
import json, sys
from evsmap.cli.main import main
try:
    code = main(sys.argv[1:])
except SystemExit as exc:
    code = exc.code
print(json.dumps({"code": code, "loaded": sorted(m for m in %r if m in sys.modules)}),
      file=sys.stderr)
"""


def _probe(*argv: str) -> dict:
    proc = subprocess.run([sys.executable, "-c", _PROBE % (HEAVY,), *argv],
                          capture_output=True, text=True, timeout=120)
    return json.loads(proc.stderr.strip().splitlines()[-1])


@pytest.mark.parametrize("argv", [("--help",), ("--version",), ("list",), ("list", "--json")])
def test_light_commands_import_no_heavy_library(argv):
    result = _probe(*argv)
    assert result["code"] == 0
    assert result["loaded"] == []


def test_info_on_tum_imports_no_heavy_library(tum_dir):
    result = _probe("info", str(tum_dir))
    assert result["code"] == 0
    assert result["loaded"] in ([], ["scipy"])  # scipy's rotations interpolate the poses


def test_report_imports_neither_torch_nor_open3d(tmp_path):
    result = _probe("report", str(tmp_path / "no-such-run"))
    assert result["code"] == 2  # a user error, not a crash
    assert "torch" not in result["loaded"] and "open3d" not in result["loaded"]


def test_open3d_loads_through_the_loader():
    # in a fresh interpreter: on a machine without Debian's libusb this is the bundled library
    code = ("from evsmap.open3d_loader import load_open3d, _bundled_libusb;"
            "o3d = load_open3d(); import evsmap.open3d_loader as m;"
            "print(o3d.__version__, m._bundled_libusb)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    version, bundled = proc.stdout.split()
    assert version.count(".") >= 2
    if not open3d_loader._system_libusb_loads():
        assert bundled.endswith("libusb-1.0.so")


def test_missing_library_is_one_line(monkeypatch):
    real_import = builtins.__import__

    def failing(name, *args, **kwargs):
        if name == "open3d":
            raise ImportError("libusb-1.0.so.0: cannot open shared object file: "
                              "No such file or directory")
        return real_import(name, *args, **kwargs)

    monkeypatch.delitem(sys.modules, "open3d", raising=False)
    monkeypatch.setattr(builtins, "__import__", failing)
    with pytest.raises(open3d_loader.MissingLibraryError) as info:
        open3d_loader.load_open3d()
    message = str(info.value)
    assert "\n" not in message
    assert "libusb-1.0.so.0 is missing" in message and "libusb-package" in message


def test_missing_library_exits_2_on_the_command_line(monkeypatch, tmp_path, capsys):
    from evsmap.cli.main import main

    def refuse():
        raise open3d_loader.MissingLibraryError(
            "open3d cannot be loaded: the shared library libGL.so.1 is missing")

    monkeypatch.setattr("evsmap.synth.render.load_open3d", refuse)
    code = main(["synth", "--out", str(tmp_path / "room"), "--frames", "1",
                 "--width", "32", "--height", "24"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "libGL.so.1 is missing" in err
    assert not (tmp_path / "room").exists()
