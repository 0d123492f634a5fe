"""Writing files and output folders safely: a reader never sees a half-written file or folder.

* :func:`atomic_path` / :func:`atomic_write` (and :func:`atomic_write_text`,
  :func:`atomic_write_bytes`): one file written under a unique temporary name beside it and moved
  into place with ``os.replace`` once complete; on an error the temporary file goes and the old
  file, if any, stays. ``durable=True`` also flushes the file and its folder to disk (training
  checkpoints, which a power cut must not lose).
* :func:`staging_folder`: the same for a whole output folder.

A write that fails for a reason the user can fix (a full disk or quota, no permission, a
read-only file system: :data:`WRITE_ERRNOS`) is raised as :class:`WriteError`, one line naming the
file it was writing (not the temporary name); the file that was there before is untouched.
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import shutil
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import IO, Any

from evsmap.errors import EvsmapError

WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EROFS,
                          errno.EFBIG})
"""OS errors that are the machine's state, not a bug: full disk or quota, no permission,
read-only file system, file too large."""


class WriteError(EvsmapError, OSError):
    """A file or folder that cannot be written (:data:`WRITE_ERRNOS`); the message names it."""


def write_error(exc: OSError, path: str | os.PathLike[str]) -> WriteError:
    """``exc`` as a :class:`WriteError` naming ``path``."""
    reason = exc.strerror or str(exc)
    return WriteError(f"cannot write {path}: {reason}")


def new_file_mode() -> int:
    """0666 less the process umask: the mode ``open`` gives a new file (``tempfile.mkstemp``
    makes 0600, which a file published by rename should not keep)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def fsync_folder(folder: str | os.PathLike[str]) -> None:
    """Flush a folder's entries (a rename into it) to disk, where the platform allows it."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # pragma: no cover  (not every platform opens folders)
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str], *, durable: bool = False,
                suffix: str = ".tmp") -> Iterator[Path]:
    """Yield a fresh temporary path beside ``path`` for a writer that takes a file name (ending
    in ``suffix``, for writers that choose the format by extension); when
    the block ends without error the file written there replaces ``path`` (``os.replace``,
    with the mode a new file gets under the umask); on error it is removed and ``path`` is left
    as it was. Missing folders above ``path`` are created first. ``durable``: flush the file and
    its folder to disk before returning.

    OS errors propagate (as :class:`OSError`); callers turn them into their own one-line error.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}{suffix}")
    try:
        if not path.parent.is_dir():
            path.parent.mkdir(parents=True, exist_ok=True)
        yield tmp
        if not tmp.exists():
            raise OSError(f"nothing was written to {tmp}")
        if durable:
            with open(tmp, "rb") as fh:
                os.fsync(fh.fileno())
        os.chmod(tmp, new_file_mode())
        os.replace(tmp, path)
        if durable:
            fsync_folder(path.parent)
    except OSError as exc:
        # a failed write of this file (not of another one the block touched) names the file
        if isinstance(exc, WriteError) or exc.errno not in WRITE_ERRNOS or \
                exc.filename not in (None, str(tmp), str(path)):
            raise
        raise write_error(exc, path) from None
    finally:
        with contextlib.suppress(OSError):
            tmp.unlink()


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike[str], mode: str = "wb", *, durable: bool = False,
                 **open_kwargs: Any) -> Iterator[IO[Any]]:
    """``with atomic_write(path, "w") as fh: ...``: :func:`atomic_path` with the file opened
    (``mode`` is ``"w"`` or ``"wb"``; ``open_kwargs`` go to :func:`open`)."""
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_write writes a new file: mode 'w' or 'wb', not {mode!r}")
    with atomic_path(path, durable=durable) as tmp, open(tmp, mode, **open_kwargs) as fh:
        yield fh


def atomic_write_text(path: str | os.PathLike[str], text: str, *, durable: bool = False) -> None:
    """``text`` (UTF-8) to ``path`` through :func:`atomic_write`."""
    with atomic_write(path, "w", durable=durable, encoding="utf-8") as fh:
        fh.write(text)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes, *,
                       durable: bool = False) -> None:
    """``data`` to ``path`` through :func:`atomic_write`."""
    with atomic_write(path, "wb", durable=durable) as fh:
        fh.write(data)


@contextlib.contextmanager
def quiet_native_output():
    """Silence what native code writes to the process's stdout and stderr for the block: a
    failed TorchScript export prints the whole traced graph (thousands of lines) from C++, a
    failed Open3D write its own error line, past Python's ``sys.stdout``. The exception (or
    the writer's return value) still says what failed."""
    import sys

    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    try:
        saved = [os.dup(1), os.dup(2)]
    except OSError:  # no file descriptors to redirect (an embedded interpreter)
        yield
        return
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, null):
            os.close(fd)


@contextlib.contextmanager
def staging_folder(out: Path, *, overwrite: bool, source: Path | None = None,
                   what: str = "") -> Iterator[Path]:
    """Yield an empty hidden folder beside ``out``; once the block ends without error it replaces
    ``out`` (so an existing ``out`` is never left half-written); on error it is removed.

    A non-empty ``out`` is refused unless ``overwrite``; ``out`` may not be or contain ``source``.
    Messages start with ``what`` (e.g. ``"--out "``) and the folder.
    """
    out = Path(out)
    name = f"{what}{out}"
    if out.exists() and not out.is_dir():
        raise EvsmapError(f"{name}: exists and is not a folder")
    dst = out.resolve()
    if source is not None:
        src = Path(source).resolve()
        if dst == src or dst in src.parents:
            raise EvsmapError(f"{name}: the output folder would replace the source {source}")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise EvsmapError(f"{name}: folder exists and is not empty (pass --overwrite)")
    parent = dst.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise EvsmapError(f"{name}: cannot create parent folder ({exc})") from None
    partial = parent / f".{dst.name}.partial-{os.getpid()}"
    shutil.rmtree(partial, ignore_errors=True)
    try:
        partial.mkdir()
        yield partial
        if dst.exists():
            old = parent / f".{dst.name}.old-{os.getpid()}"
            dst.rename(old)
            try:
                partial.rename(dst)
            except BaseException:  # an interruption between the two renames: put it back
                old.rename(dst)
                raise
            shutil.rmtree(old, ignore_errors=True)
        else:
            partial.rename(dst)
    except WriteError:
        raise
    except OSError as exc:
        raise WriteError(f"{name}: cannot write ({exc.strerror or exc})") from None
    finally:
        shutil.rmtree(partial, ignore_errors=True)


def read_json_object(path: str | os.PathLike[str]) -> dict:
    """The JSON object in ``path``, or ``{}`` when the file is missing, unreadable or holds
    something else (small state files that are rebuilt when lost: calibrations, durations)."""
    import json

    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def renamed_keys(data: Mapping[str, Any], old_keys: Mapping[str, str]) -> dict[str, Any]:
    """A stored record ``data`` with the keys it was written under renamed by ``old_keys``
    (old -> current; a key already present under its current name wins); the order is kept.
    The one rule by which evsmap reads files written before a key was renamed."""
    out: dict[str, Any] = {}
    for key, value in data.items():
        new = old_keys.get(key, key)
        if new != key and new in data:
            continue
        out[new] = value
    return out
