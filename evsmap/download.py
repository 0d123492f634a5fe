"""Downloading: HTTP(S) with resume, progress, checks and staging (the mechanics behind
``evsmap datasets fetch``; :mod:`evsmap.fetch` applies them to the sample catalogue).

* :func:`remote_size` asks the server for a file's size (a ``HEAD`` request; redirects keep the
  method) so that a multi-GB download can be announced and confirmed before it starts.
* :func:`download` fetches a URL into a cache folder through ``<name>.part``: an interrupted
  transfer is resumed with an HTTP ``Range`` request (by the next attempt, or by the next call);
  the finished file is checked against the expected size and sha256 (when known) and only then
  renamed to ``<name>``. A file that fails its check is deleted.

Every failure is a :class:`FetchError` (an :class:`~evsmap.errors.EvsmapError`: one line naming the
URL or file, exit status 2 on the command line). Only the standard library does the HTTP.
"""

from __future__ import annotations

import contextlib
import hashlib
import http.client
import os
import shutil
import sys
import tempfile
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path

from evsmap.errors import EvsmapError
from evsmap.paths import user_cache_dir

MIRROR_ENV = "EVSMAP_SAMPLES_MIRROR"
"""Environment variable: a base URL serving the archives under their file names
(``$EVSMAP_SAMPLES_MIRROR/<file name>`` replaces each official URL), e.g. a lab mirror."""
CACHE_ENV = "EVSMAP_DOWNLOAD_DIR"
"""Environment variable: the download cache folder (default ``~/.cache/evsmap/downloads``)."""
MANIFEST = "evsmap-sample.json"
"""Manifest of a fetched sample: inside its folder, or ``<file>.evsmap-sample.json`` beside a
single-file sample."""
MANIFEST_FORMAT = "evsmap-sample"
CHUNK = 1 << 20
TIMEOUT = 60.0
"""Seconds without data before a connection counts as lost."""
RETRIES = 3
"""Attempts after the first when a transfer breaks off (each resumes where the last stopped)."""
RETRY_DELAY = 2.0
"""Seconds before the first retry (doubled for each further one, at most 30)."""


class FetchError(EvsmapError):
    """A download or sample fetch that failed (one line naming the URL or file)."""


class CorruptArchiveError(FetchError):
    """A downloaded archive that cannot be read (truncated, damaged, not the expected format):
    :func:`fetch_sample` deletes it, so that the next call downloads it again."""

    def __init__(self, message: str, path: Path) -> None:
        super().__init__(message)
        self.path = Path(path)


# -- small helpers ------------------------------------------------------------------------------
def default_cache_dir() -> Path:
    """``$EVSMAP_DOWNLOAD_DIR``, else ``~/.cache/evsmap/downloads`` (``$XDG_CACHE_HOME``)."""
    env = os.environ.get(CACHE_ENV)
    return Path(env).expanduser() if env else user_cache_dir() / "downloads"


def format_size(n: int | None) -> str:
    """``3.8 MB``, ``2.97 GB`` (decimal units), ``unknown size`` for ``None``."""
    if n is None:
        return "unknown size"
    if n < 1000:
        return f"{n} B"
    for unit, scale in (("kB", 1e3), ("MB", 1e6), ("GB", 1e9), ("TB", 1e12)):
        if n < scale * 1000 or unit == "TB":
            value = n / scale
            return f"{value:.2f} {unit}" if value < 10 else f"{value:.1f} {unit}"
    raise AssertionError("unreachable")  # pragma: no cover


def _bar(total: int | None, initial: int, desc: str):
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit="B", unit_scale=True,
                unit_divisor=1024, leave=False, disable=not sys.stderr.isatty(),
                file=sys.stderr)


def sha256_file(path: Path, *, desc: str | None = None) -> str:
    """Hex sha256 of a file (a progress bar on a terminal when ``desc`` is given)."""
    h = hashlib.sha256()
    size = Path(path).stat().st_size
    with open(path, "rb") as fh, _bar(size, 0, desc or "") if desc else contextlib.nullcontext() \
            as bar:
        while chunk := fh.read(CHUNK):
            h.update(chunk)
            if bar is not None:
                bar.update(len(chunk))
    return h.hexdigest()


def _user_agent() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"evsmap/{version('evsmap')} (datasets fetch)"
    except PackageNotFoundError:
        return "evsmap (datasets fetch)"



def _reason(exc: BaseException) -> str:
    if isinstance(exc, urllib.error.URLError) and not isinstance(exc, urllib.error.HTTPError):
        exc = exc.reason if isinstance(exc.reason, BaseException) else exc
    text = str(exc) or type(exc).__name__
    if isinstance(exc, http.client.IncompleteRead):
        text = "connection closed early"
    return " ".join(text.split())


class _KeepMethodRedirect(urllib.request.HTTPRedirectHandler):
    """Redirects that keep ``HEAD`` a ``HEAD`` (urllib turns every redirect into a ``GET``)."""

    def redirect_request(self, req, fp, code, msg, headers, newurl):
        new = super().redirect_request(req, fp, code, msg, headers, newurl)
        if new is not None and req.get_method() == "HEAD":
            new.method = "HEAD"
        return new


_OPENER = urllib.request.build_opener(_KeepMethodRedirect)


def _open(url: str, *, method: str = "GET", headers: dict[str, str] | None = None,
          timeout: float):
    req = urllib.request.Request(url, method=method, headers={
        "User-Agent": _user_agent(), "Accept-Encoding": "identity", **(headers or {})})
    return _OPENER.open(req, timeout=timeout)


# -- HTTP ---------------------------------------------------------------------------------------
def remote_size(url: str, *, timeout: float | None = None) -> int | None:
    """The size the server reports for ``url`` (``HEAD``'s Content-Length), ``None`` when it does
    not say. A missing file (404 and other error statuses) or an unreachable host is a
    :class:`FetchError`; a server that refuses ``HEAD`` itself (405, 501) gives ``None``."""
    try:
        with _open(url, method="HEAD", timeout=TIMEOUT if timeout is None else timeout) as resp:
            length = resp.headers.get("Content-Length")
    except urllib.error.HTTPError as exc:
        if exc.code in (405, 501):
            return None
        raise FetchError(f"{url}: HTTP {exc.code} {exc.reason}") from None
    except (urllib.error.URLError, OSError, http.client.HTTPException) as exc:
        raise FetchError(f"{url}: cannot connect ({_reason(exc)})") from None
    try:
        return int(length) if length is not None else None
    except ValueError:
        return None


def _content_range(value: str | None) -> tuple[int, int | None] | None:
    """``bytes START-END/TOTAL`` -> (START, TOTAL or None)."""
    if not value or not value.startswith("bytes "):
        return None
    span, _, total = value[6:].partition("/")
    start = span.partition("-")[0]
    try:
        return int(start), (None if total.strip() in ("", "*") else int(total))
    except ValueError:
        return None


def download(url: str, dest: Path, *, size: int | None = None, sha256: str | None = None,
             retries: int = RETRIES, timeout: float | None = None,
             log: Callable[[str], None] | None = None) -> Path:
    """Download ``url`` to ``dest`` through ``dest.part``, resuming a ``.part`` left by an earlier
    call, and check the result.

    ``size``/``sha256`` are the expected size and hex sha256 (``None``: not known; the size is
    then the server's Content-Length). A transfer that breaks off is resumed with a ``Range``
    request up to ``retries`` more times, then the ``.part`` is kept for the next call and a
    :class:`FetchError` says so. A result of the wrong size or sha256 is deleted. An existing
    ``dest`` is kept when it passes the checks (and downloaded again when it does not).
    """
    dest = Path(dest)
    timeout = TIMEOUT if timeout is None else timeout
    if dest.is_file():
        if _matches(dest, size, sha256):
            return dest
        dest.unlink()
    part = dest.with_name(dest.name + ".part")
    total = size
    failures = 0
    say = log or (lambda _msg: None)
    while True:
        offset = part.stat().st_size if part.is_file() else 0
        if total is not None and offset > total:
            part.unlink()  # more than the whole file: not a prefix of it
            offset = 0
        if total is not None and offset == total:
            break
        headers = {"Range": f"bytes={offset}-"} if offset else {}
        try:
            resp = _open(url, headers=headers, timeout=timeout)
        except urllib.error.HTTPError as exc:
            if exc.code == 416 and offset:
                # nothing left to send from here: the .part is complete, or not this file
                if total is None:  # "bytes */TOTAL"
                    tail = (exc.headers.get("Content-Range") or "").rpartition("/")[2].strip()
                    total = int(tail) if tail.isdigit() else None
                if total == offset:
                    break
                part.unlink()
                failures += 1
                if failures > retries:
                    raise FetchError(f"{url}: the server refuses to resume from byte {offset} "
                                     "(HTTP 416); the partial download was deleted") from None
                continue
            raise FetchError(f"{url}: HTTP {exc.code} {exc.reason}") from None
        except (urllib.error.URLError, OSError, http.client.HTTPException) as exc:
            failures += 1
            if failures > retries:
                kept = f"; run the command again to resume from {part}" if offset else ""
                raise FetchError(f"{url}: cannot connect ({_reason(exc)}){kept}") from None
            say(f"  {url}: {_reason(exc)}; retrying")
            time.sleep(min(RETRY_DELAY * 2 ** (failures - 1), 30.0))
            continue
        with resp:
            if resp.status == 206:
                crange = _content_range(resp.headers.get("Content-Range"))
                if crange is None or crange[0] != offset:
                    raise FetchError(f"{url}: asked for bytes {offset}- and got "
                                     f"{resp.headers.get('Content-Range')!r}")
                if crange[1] is not None:
                    if total is not None and crange[1] != total:
                        raise FetchError(f"{url}: the server has {crange[1]} bytes, expected "
                                         f"{total}")
                    total = crange[1]
                mode = "ab"
            elif resp.status == 200:
                if offset:
                    say(f"  {url}: the server does not resume; starting again")
                offset = 0
                length = resp.headers.get("Content-Length")
                if length is not None and length.isdigit():
                    if total is not None and int(length) != total:
                        raise FetchError(f"{url}: the server sends {length} bytes, expected "
                                         f"{total}")
                    total = int(length)
                mode = "wb"
            else:
                raise FetchError(f"{url}: unexpected HTTP status {resp.status}")
            error = _receive(resp, part, mode, total, offset, dest.name)
        got = part.stat().st_size if part.is_file() else 0
        if error is None and (total is None or got >= total):
            break
        failures += 1
        why = _reason(error) if error is not None else "connection closed early"
        if failures > retries:
            raise FetchError(f"{url}: connection lost after {got} of "
                             f"{total if total is not None else '?'} bytes ({why}); run the "
                             f"command again to resume from {part}")
        say(f"  {url}: {why} after {got} bytes; resuming")
        time.sleep(min(RETRY_DELAY * 2 ** (failures - 1), 30.0))
    got = part.stat().st_size
    if total is not None and got != total:
        part.unlink()
        raise FetchError(f"{url}: got {got} bytes, expected {total}; the download was deleted")
    if sha256 is not None:
        digest = sha256_file(part, desc=f"checking {dest.name}")
        if digest != sha256.lower():
            part.unlink()
            raise FetchError(f"{url}: sha256 {digest} is not the expected {sha256.lower()}; the "
                             "download was deleted")
    part.replace(dest)
    return dest


def _receive(resp, part: Path, mode: str, total: int | None, offset: int, desc: str
             ) -> BaseException | None:
    """Append (``ab``) or write (``wb``) the body of ``resp`` to ``part``; the network error that
    ended it early, or ``None``."""
    try:
        part.parent.mkdir(parents=True, exist_ok=True)
        fh = open(part, mode)  # noqa: SIM115 (closed below)
    except OSError as exc:
        raise FetchError(f"{part}: cannot write ({_reason(exc)})") from None
    with fh, _bar(total, offset, desc) as bar:
        while True:
            try:
                chunk = resp.read(CHUNK)
            except (OSError, http.client.HTTPException) as exc:
                return exc
            if not chunk:
                return None
            try:
                fh.write(chunk)
            except OSError as exc:
                raise FetchError(f"{part}: cannot write ({_reason(exc)})") from None
            bar.update(len(chunk))


def _matches(path: Path, size: int | None, sha256: str | None) -> bool:
    if size is not None and path.stat().st_size != size:
        return False
    return sha256 is None or sha256_file(path, desc=f"checking {path.name}") == sha256.lower()


# -- staging ------------------------------------------------------------------------------------
@contextlib.contextmanager
def staging_file(target: Path, *, overwrite: bool) -> Iterator[Path]:
    """Yield an empty hidden folder beside the file ``target``; when the block ends without error,
    the file of ``target``'s name written into it (and its manifest, if any) replace ``target``.
    On error the folder is removed and ``target`` is untouched."""
    target = Path(target)
    if target.exists() and not overwrite:
        raise FetchError(f"{target}: exists (pass --overwrite to replace it)")
    if target.exists() and not target.is_file():
        raise FetchError(f"{target}: exists and is not a file")
    parent = target.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=f".{target.name}.partial-", dir=parent))
    except OSError as exc:
        raise FetchError(f"{target}: cannot create the folder ({exc})") from None
    try:
        yield stage
        manifest = stage / f"{target.name}.{MANIFEST}"
        if manifest.is_file():
            manifest.replace(parent / manifest.name)
        (stage / target.name).replace(target)
    except OSError as exc:
        raise FetchError(f"{target}: cannot write ({exc})") from None
    finally:
        shutil.rmtree(stage, ignore_errors=True)
