"""Downloading through pooch: the mechanics behind ``evsmap datasets fetch`` (:mod:`evsmap.fetch`
applies them to the sample catalogue).

* :func:`remote_size` asks the server for a file's size (a ``HEAD`` request, redirects followed
  as ``HEAD``) so that a multi-GB download can be announced and confirmed before it starts.
* :func:`download` gets a URL into a cache folder with :meth:`pooch.Pooch.fetch`: pooch keeps a
  cached file whose sha256 matches, downloads into a temporary file, checks the sha256 (deleting
  a file that fails it) and renames it into place. The transfer itself is
  :class:`ResumingDownloader`, a pooch downloader that writes ``<name>.part`` and resumes it with
  HTTP ``Range`` requests (by the next attempt, or by the next call), with a progress bar on a
  terminal only.

Every failure is a :class:`FetchError` (an :class:`~evsmap.errors.EvsmapError`: one line naming the
URL or file, exit status 2 on the command line).
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import re
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

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

Log = Callable[[str], None]


class FetchError(EvsmapError):
    """A download or sample fetch that failed (one line naming the URL or file)."""


class CorruptArchiveError(FetchError):
    """A downloaded archive that cannot be read (truncated, damaged, not the expected format):
    :func:`~evsmap.fetch.fetch_sample` deletes it, so that the next call downloads it again."""

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


def _bar(total: int | None, initial: int, desc: str) -> Any:
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


def _headers() -> dict[str, str]:
    from importlib.metadata import PackageNotFoundError, version

    try:
        agent = f"evsmap/{version('evsmap')} (datasets fetch)"
    except PackageNotFoundError:
        agent = "evsmap (datasets fetch)"
    return {"User-Agent": agent, "Accept-Encoding": "identity"}


def _reason(exc: BaseException) -> str:
    """The innermost cause of a network error in a few words (requests wraps urllib3's errors,
    which wrap the socket's)."""
    from http.client import IncompleteRead as ShortBody

    from urllib3.exceptions import IncompleteRead, MaxRetryError

    seen: set[int] = set()
    while id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, (IncompleteRead, ShortBody)):
            return "connection closed early"
        inner = exc.reason if isinstance(exc, MaxRetryError) else next(
            (a for a in exc.args if isinstance(a, BaseException)), None) or exc.__cause__
        if inner is None:
            break
        exc = inner
    return " ".join((str(exc) or type(exc).__name__).split())


def _request(method: str, url: str, *, timeout: float, offset: int = 0) -> Any:
    """A streamed ``requests`` response (redirects followed, ``Range`` from ``offset``); a URL
    that is not HTTP(S) is a :class:`FetchError`, a network error a ``RequestException``."""
    import requests

    headers = _headers() | ({"Range": f"bytes={offset}-"} if offset else {})
    try:
        return requests.request(method, url, headers=headers, timeout=timeout, stream=True,
                                allow_redirects=True)
    except (requests.exceptions.InvalidURL, requests.exceptions.InvalidSchema,
            requests.exceptions.MissingSchema) as exc:
        raise FetchError(f"{url}: not an HTTP(S) URL ({_reason(exc)})") from None


# -- HTTP ---------------------------------------------------------------------------------------
def remote_size(url: str, *, timeout: float | None = None) -> int | None:
    """The size the server reports for ``url`` (``HEAD``'s Content-Length), ``None`` when it does
    not say. A missing file (404 and other error statuses) or an unreachable host is a
    :class:`FetchError`; a server that refuses ``HEAD`` itself (405, 501) gives ``None``."""
    import requests

    try:
        with _request("HEAD", url, timeout=TIMEOUT if timeout is None else timeout) as resp:
            status, why, length = resp.status_code, resp.reason, resp.headers.get("Content-Length")
    except (requests.RequestException, OSError) as exc:
        raise FetchError(f"{url}: cannot connect ({_reason(exc)})") from None
    if status in (405, 501):
        return None
    if status >= 400:
        raise FetchError(f"{url}: HTTP {status} {why}")
    try:
        return int(length) if length is not None else None
    except ValueError:
        return None


def download(url: str, dest: Path, *, size: int | None = None, sha256: str | None = None,
             retries: int = RETRIES, timeout: float | None = None,
             log: Log | None = None) -> Path:
    """Download ``url`` to ``dest`` (through ``dest.part``, resuming one left by an earlier call)
    with pooch, and check the result.

    ``size``/``sha256`` are the expected size and hex sha256 (``None``: not known; the size is
    then the server's Content-Length). A transfer that breaks off is resumed up to ``retries``
    more times, then the ``.part`` is kept for the next call and a :class:`FetchError` says so.
    A result of the wrong size or sha256 is deleted. An existing ``dest`` is kept when it passes
    the checks (and downloaded again when it does not).
    """
    import pooch

    dest = Path(dest)
    if dest.is_file() and size is not None and dest.stat().st_size != size:
        dest.unlink()  # pooch checks the sha256 only
    known = f"sha256:{sha256.lower()}" if sha256 else None
    getter = ResumingDownloader(dest, size=size, retries=retries, log=log,
                                timeout=TIMEOUT if timeout is None else timeout)
    store = pooch.Pooch(path=dest.parent, base_url="", registry={dest.name: known},
                        urls={dest.name: url})
    _mkdir(dest.parent, getter.part)
    try:
        with _quiet(pooch.get_logger()):
            store.fetch(dest.name, downloader=getter)
    except ValueError as exc:  # pooch: the sha256 does not match (the download is deleted)
        if "does not match the known hash" not in str(exc):
            raise
        got = re.search(r"but got (\w+)", str(exc))
        raise FetchError(f"{url}: sha256 {got.group(1) if got else '?'} is not the expected "
                         f"{sha256.lower() if sha256 else '?'}; the download was deleted") \
            from None
    except OSError as exc:
        raise FetchError(f"{dest.parent}: cannot write ({_reason(exc)})") from None
    return dest


def _mkdir(folder: Path, part: Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FetchError(f"{part}: cannot write ({_reason(exc)})") from None


@contextlib.contextmanager
def _quiet(logger: logging.Logger) -> Iterator[None]:
    """pooch's log (to stderr) held to warnings: evsmap says what it does itself."""
    level = logger.level
    logger.setLevel(logging.WARNING)
    try:
        yield
    finally:
        logger.setLevel(level)


@dataclass
class _Broken:
    """An attempt that may be tried again: the error if it was the last, the note before the
    next (``None``: none), whether to wait first."""

    final: str
    note: str | None
    wait: bool = True


class ResumingDownloader:
    """A pooch downloader (``downloader(url, output_file, pooch)``) that transfers through
    ``dest.part``: a transfer that breaks off is resumed with an HTTP ``Range`` request up to
    ``retries`` more times (the ``.part`` is kept for a later call after that); the complete
    ``.part`` of the right size becomes pooch's ``output_file``, which pooch then checks."""

    def __init__(self, dest: Path, *, size: int | None, retries: int, timeout: float,
                 log: Log | None) -> None:
        self.dest = Path(dest)
        self.part = self.dest.with_name(self.dest.name + ".part")
        self.total = size
        self.retries = retries
        self.timeout = timeout
        self.say: Log = log or (lambda _msg: None)

    def __call__(self, url: str, output_file: str, pooch: Any, check_only: bool = False) -> None:
        self.dest.unlink(missing_ok=True)  # pooch found it missing or failing its check
        failures = 0
        while (broken := self._attempt(url)) is not None:
            failures += 1
            if failures > self.retries:
                raise FetchError(broken.final)
            if broken.note is not None:
                self.say(broken.note)
            if broken.wait:
                time.sleep(min(RETRY_DELAY * 2 ** (failures - 1), 30.0))
        got = self._have()
        if self.total is not None and got != self.total:
            self.part.unlink()
            raise FetchError(f"{url}: got {got} bytes, expected {self.total}; the download was "
                             "deleted")
        self.part.replace(output_file)

    def _have(self) -> int:
        return self.part.stat().st_size if self.part.is_file() else 0

    def _attempt(self, url: str) -> _Broken | None:
        """One request from where the ``.part`` ends; ``None`` once the ``.part`` is complete."""
        import requests

        offset = self._have()
        if self.total is not None and offset > self.total:
            self.part.unlink()  # more than the whole file: not a prefix of it
            offset = 0
        if self.total is not None and offset == self.total:
            return None
        try:
            resp = _request("GET", url, timeout=self.timeout, offset=offset)
        except (requests.RequestException, OSError) as exc:
            kept = f"; run the command again to resume from {self.part}" if offset else ""
            return _Broken(f"{url}: cannot connect ({_reason(exc)}){kept}",
                           f"  {url}: {_reason(exc)}; retrying")
        with resp:
            if resp.status_code == 416 and offset:
                return self._refused(url, resp, offset)
            mode = self._accept(url, resp, offset)
            error = self._receive(resp, mode)
        got = self._have()
        if error is None and (self.total is None or got >= self.total):
            return None
        why = _reason(error) if error is not None else "connection closed early"
        total = self.total if self.total is not None else "?"
        return _Broken(f"{url}: connection lost after {got} of {total} bytes ({why}); run the "
                       f"command again to resume from {self.part}",
                       f"  {url}: {why} after {got} bytes; resuming")

    def _refused(self, url: str, resp: Any, offset: int) -> _Broken | None:
        """HTTP 416: nothing left to send from ``offset``: the ``.part`` is complete, or it is not
        this file (then it is deleted)."""
        if self.total is None:  # "bytes */TOTAL"
            tail = (resp.headers.get("Content-Range") or "").rpartition("/")[2].strip()
            self.total = int(tail) if tail.isdigit() else None
        if self.total == offset:
            return None
        self.part.unlink()
        return _Broken(f"{url}: the server refuses to resume from byte {offset} (HTTP 416); the "
                       "partial download was deleted", None, wait=False)

    def _accept(self, url: str, resp: Any, offset: int) -> str:
        """Check the answer to a request from ``offset`` against what is known of the file; the
        mode to open the ``.part`` in (``ab`` to append, ``wb`` to start again)."""
        status = resp.status_code
        if status == 206:
            crange = _content_range(resp.headers.get("Content-Range"))
            if crange is None or crange[0] != offset:
                raise FetchError(f"{url}: asked for bytes {offset}- and got "
                                 f"{resp.headers.get('Content-Range')!r}")
            if crange[1] is not None:
                if self.total is not None and crange[1] != self.total:
                    raise FetchError(f"{url}: the server has {crange[1]} bytes, expected "
                                     f"{self.total}")
                self.total = crange[1]
            return "ab"
        if status == 200:
            if offset:
                self.say(f"  {url}: the server does not resume; starting again")
            length = resp.headers.get("Content-Length")
            if length is not None and length.isdigit():
                if self.total is not None and int(length) != self.total:
                    raise FetchError(f"{url}: the server sends {length} bytes, expected "
                                     f"{self.total}")
                self.total = int(length)
            return "wb"
        if status >= 400:
            raise FetchError(f"{url}: HTTP {status} {resp.reason}")
        raise FetchError(f"{url}: unexpected HTTP status {status}")

    def _receive(self, resp: Any, mode: str) -> BaseException | None:
        """Append (``ab``) or write (``wb``) the body of ``resp`` to the ``.part``; the network
        error that ended it early, or ``None``."""
        from http.client import HTTPException

        from urllib3.exceptions import HTTPError

        try:
            fh: IO[bytes] = open(self.part, mode)  # noqa: SIM115 (closed below)
        except OSError as exc:
            raise FetchError(f"{self.part}: cannot write ({_reason(exc)})") from None
        with fh, _bar(self.total, self._have(), self.dest.name) as bar:
            while True:
                try:  # read1: what has arrived (read would drop it when the connection breaks)
                    chunk = resp.raw.read1(CHUNK)
                except (HTTPError, HTTPException, OSError) as exc:
                    return exc
                if not chunk:
                    return None
                try:
                    fh.write(chunk)
                except OSError as exc:
                    raise FetchError(f"{self.part}: cannot write ({_reason(exc)})") from None
                bar.update(len(chunk))


def _content_range(value: str | None) -> tuple[int, int | None] | None:
    """``bytes START-END/TOTAL`` -> (START, TOTAL or None)."""
    match = re.fullmatch(r"bytes (\d+)-\d*(?:/(\d+|\*))?\s*", value or "")
    if match is None:
        return None
    return int(match[1]), (None if match[2] in (None, "*") else int(match[2]))
