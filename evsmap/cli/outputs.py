"""The output policy of every command that writes (``map``, ``synth``, ``predict``, ``train``,
``weights convert``, ``datasets prepare``, ``datasets fetch``, ``gate --results``,
``reproduce --out``): one home for it.

* An existing output is refused unless ``--overwrite`` (an empty folder is not an output yet).
* Every output path is checked before any work starts: its folder (or the nearest folder above
  it that exists) must be a folder this process can create a file in, a file output may not be
  a folder, a folder output may not be a file, and two outputs of one command may not be the same
  path. Missing folders above an output are created when it is written.
* Outputs are written by rename (:mod:`evsmap.fileio`): an interrupted or failed command leaves
  the file or folder that was there before.
* A refusal is one line that names the option and the path once, and the fix where there is one.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from evsmap.errors import EvsmapError


@dataclass(frozen=True)
class Output:
    """One path a command will write.

    Args:
        option: the option that named it (``--out``), for messages.
        path: the file or folder.
        folder: whether the output is a folder (written whole through a staging folder).
        suffixes: the endings a file output may have (empty: any).
        in_place: a folder written into where it is (a training run, a report run, which
            continue or resume there): an existing one is not refused, and the files must be
            creatable inside it.
    """

    option: str
    path: Path
    folder: bool = False
    suffixes: tuple[str, ...] = ()
    in_place: bool = False

    @property
    def label(self) -> str:
        return f"{self.option} {self.path}"


def claim_outputs(outputs: Iterable[Output | None], *, overwrite: bool,
                  overwrite_option: str = "--overwrite") -> None:
    """Check every output before the command does any work (see the module's rules).

    Raises:
        EvsmapError: one line naming the option and the path.
    """
    claimed = [o for o in outputs if o is not None]
    seen: dict[Path, Output] = {}
    for out in claimed:
        key = Path(os.path.abspath(out.path))
        if key in seen:
            raise EvsmapError(f"{seen[key].option} and {out.option} name the same path "
                              f"{out.path}: give each its own")
        seen[key] = out
        _check_one(out, overwrite=overwrite, overwrite_option=overwrite_option)


def _check_one(out: Output, *, overwrite: bool, overwrite_option: str) -> None:
    path = out.path
    if out.suffixes and not out.folder and path.suffix not in out.suffixes:
        raise EvsmapError(f"{out.label}: the file name must end in "
                          f"{' or '.join(out.suffixes)}")
    if out.folder:
        if path.exists() and not path.is_dir():
            raise EvsmapError(f"{out.label}: exists and is a file, not a folder")
        if path.is_dir() and any(path.iterdir()) and not overwrite and not out.in_place:
            raise EvsmapError(f"{out.label}: folder exists and is not empty (pass "
                              f"{overwrite_option} to replace it once the new one is complete)")
    else:
        if path.is_dir():
            raise EvsmapError(f"{out.label}: is a folder; give a file name")
        if path.exists() and not overwrite:
            raise EvsmapError(f"{out.label}: exists (pass {overwrite_option} to replace it)")
    check_writable(out)


def check_writable(out: Output) -> None:
    """That a file can be created where ``out`` goes: in its folder (in the folder itself for an
    ``in_place`` folder that exists), or where that folder does not exist yet in the nearest
    folder above it that does; tried by creating and removing a hidden file, which also catches
    a read-only file system and a full quota of inodes."""
    path = Path(os.path.abspath(out.path))
    folder = path if out.in_place and path.is_dir() else path.parent
    while not folder.exists():
        folder = folder.parent
    if not folder.is_dir():
        raise EvsmapError(f"{out.label}: {folder} is a file, not a folder")
    probe = folder / f".evsmap-write-check.{os.getpid()}.{secrets.token_hex(4)}"
    try:
        fd = os.open(probe, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise EvsmapError(f"{out.label}: cannot write in {folder} ({reason})") from None
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(probe)
