"""The one place evsmap imports Open3D.

Open3D's Linux wheels link against the system's ``libusb-1.0.so.0`` (Debian's ``libusb-1.0-0``),
which a fresh machine often lacks; importing open3d then fails with ``ImportError:
libusb-1.0.so.0: cannot open shared object file``. PyPI's ``libusb-package`` ships the same
library (soname ``libusb-1.0.so.0``): loaded once with ``RTLD_GLOBAL`` before open3d, the dynamic
linker resolves open3d's dependency to it, so no system package is needed. This is done only when
the system library cannot be loaded; the system's copy is always preferred.

Everything that needs Open3D calls :func:`load_open3d` inside the function that uses it, so the
command line starts without it (``evsmap --help`` never pays for Open3D).
"""

from __future__ import annotations

import ctypes
import re
import sys
from types import ModuleType

from evsmap.errors import EvsmapError

LIBUSB_SONAME = "libusb-1.0.so.0"

_bundled_libusb: str | None = None
"""The path of ``libusb-package``'s library when it was loaded (``None``: not needed or absent)."""


class MissingLibraryError(EvsmapError):
    """A compiled library that a dependency needs cannot be loaded."""


def _system_libusb_loads() -> bool:
    try:
        ctypes.CDLL(LIBUSB_SONAME)
    except OSError:
        return False
    return True


def ensure_libusb() -> str | None:
    """Make ``libusb-1.0.so.0`` loadable; returns the bundled library's path when that was used.

    Only on Linux, and only when the system library does not load.
    """
    global _bundled_libusb
    if not sys.platform.startswith("linux") or _bundled_libusb or _system_libusb_loads():
        return _bundled_libusb
    try:
        import libusb_package
    except ImportError:
        return None
    path = libusb_package.get_library_path()
    if path is None:
        return None
    try:
        ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
    except OSError:
        return None
    _bundled_libusb = str(path)
    return _bundled_libusb


def load_open3d() -> ModuleType:
    """``import open3d``, after :func:`ensure_libusb`.

    Raises:
        MissingLibraryError: open3d is not installed, or a shared library it links against is
            missing (one line naming the library and how to get it).
    """
    if "open3d" in sys.modules:
        return sys.modules["open3d"]
    ensure_libusb()
    try:
        import open3d
    except ImportError as exc:
        text = str(exc)
        match = re.search(r"([\w.+-]+\.so[\w.]*): cannot open shared object file", text)
        if match is None:
            raise MissingLibraryError(
                f"open3d cannot be imported ({text.splitlines()[0] if text else exc!r}); "
                "install evsmap's dependencies: pip install -c constraints.txt -e .") from None
        lib = match.group(1)
        hint = ("pip install libusb-package (or apt-get install libusb-1.0-0)"
                if lib.startswith("libusb") else f"install the system package providing {lib}")
        raise MissingLibraryError(
            f"open3d cannot be loaded: the shared library {lib} is missing; {hint}") from None
    return open3d
