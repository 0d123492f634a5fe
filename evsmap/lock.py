"""The dependency lock (``constraints.txt``) and how the running environment compares with it.

``constraints.txt`` pins every runtime and test dependency (``nox -s lock`` regenerates it with
pip-tools); every nox session and ``.ci/run`` install through it. A run record stores the lock's
sha256 and any installed version that differs from its pin, so a past run's environment can be
rebuilt (check out the record's git commit and install through that commit's lock) and a run made
outside the lock is visible in its report.
"""

from __future__ import annotations

import hashlib
import re
from importlib import metadata
from pathlib import Path
from typing import Any

from evsmap.paths import REPO_ROOT

LOCK_FILE = REPO_ROOT / "constraints.txt"

_PIN = re.compile(r"^([A-Za-z0-9][A-Za-z0-9._-]*)==([^\s;#]+)")


def normalize(name: str) -> str:
    """PEP 503 name normalisation (``Foo_bar`` -> ``foo-bar``)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def read_pins(path: Path = LOCK_FILE) -> dict[str, str]:
    """``{normalised name: version}`` of every ``name==version`` line of a requirements file."""
    pins = {}
    for line in path.read_text().splitlines():
        m = _PIN.match(line.strip())
        if m:
            pins[normalize(m.group(1))] = m.group(2)
    return pins


def _public(version: str) -> str:
    return version.split("+", 1)[0]  # 2.13.0+cpu satisfies ==2.13.0


def installed_versions() -> dict[str, str]:
    """The installed distributions' versions as Python resolves them: the first of a name on
    the import path wins (what ``importlib.metadata.version`` returns), and the copies other
    packages vendor are not installed distributions (setuptools puts its ``_vendor`` folder,
    with the metadata of the wheel, zipp and platformdirs it bundles, on ``sys.path`` once it
    is imported, as torch.compile's C++ builder does)."""
    found: dict[str, str] = {}
    for dist in metadata.distributions():
        name = dist.metadata["Name"]
        where = str(getattr(dist, "_path", ""))
        if not name or "/_vendor/" in where.replace("\\", "/"):
            continue
        found.setdefault(normalize(name), dist.version)
    return found


def lock_status(path: Path = LOCK_FILE) -> dict[str, Any] | None:
    """The lock's sha256 and pin count, and the installed distributions that differ from it.

    ``differs`` maps a name to ``[locked, installed]``; a pinned package that is not installed is
    not listed (extras such as ``dev`` need not be installed). ``None`` when there is no lock
    file (an installed package used outside its checkout).
    """
    if not path.is_file():
        return None
    pins = read_pins(path)
    installed = installed_versions()
    differs = {name: [pins[name], installed[name]] for name in sorted(pins)
               if name in installed and _public(installed[name]) != _public(pins[name])}
    return {"file": path.name, "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
            "pins": len(pins), "installed_pins": sum(n in installed for n in pins),
            "differs": differs}
