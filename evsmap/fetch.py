"""``evsmap datasets fetch``: one sample of :data:`evsmap.samples.SAMPLES` made from its official
files - size and confirmation, downloads through pooch (:func:`evsmap.download.download`),
extraction into a staging folder (:mod:`evsmap.sample_archives`), verification against the
catalogue, a manifest (``evsmap-sample.json``), then a rename into place: an interrupted or failed
fetch leaves nothing half-written in the output.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from evsmap import download as _download
from evsmap.download import (
    MANIFEST,
    MANIFEST_FORMAT,
    MIRROR_ENV,
    RETRIES,
    CorruptArchiveError,
    FetchError,
    Log,
    default_cache_dir,
    format_size,
    remote_size,
    sha256_file,
)
from evsmap.errors import EvsmapError
from evsmap.sample_archives import extract_sample
from evsmap.samples import SAMPLES, Sample, Source, verify_sample
from evsmap.version import evsmap_version

CONFIRM_BYTES = 1_000_000_000
"""Downloads of this many bytes or more need ``--yes`` (or a "y" at the prompt)."""


def manifest_path(sample: Sample, root: Path) -> Path:
    """Where the manifest of ``sample`` under the data root ``root`` is (or would be)."""
    target = Path(root) / sample.folder
    if sample.single_file:
        return target.with_name(f"{target.name}.{MANIFEST}")
    return target / MANIFEST


def read_sample_manifest(sample: Sample, root: Path) -> dict | None:
    """The manifest written by :func:`fetch_sample`, ``None`` when absent or unreadable."""
    path = manifest_path(sample, root)
    try:
        record = json.loads(path.read_text())
    except (OSError, ValueError, RecursionError):  # ValueError: JSON, UTF-8, integer digits
        return None
    return record if isinstance(record, dict) and record.get("format") == MANIFEST_FORMAT \
        else None


def source_url(url: str, filename: str, mirror: str | None) -> str:
    """``url``, or ``mirror/filename`` when a mirror is given (``mirror``, else
    ``$EVSMAP_SAMPLES_MIRROR``)."""
    base = mirror if mirror is not None else os.environ.get(MIRROR_ENV) or None
    return f"{base.rstrip('/')}/{filename}" if base else url


@dataclass
class _Plan:
    url: str
    dest: Path
    size: int | None  # expected size (catalogue or server), None unknown
    sha256: str | None
    to_download: int | None  # bytes still to fetch; None unknown
    large: bool


def fetch_sample(sample: Sample | str, out_root: str | Path | None = None, *,
                 overwrite: bool = False, yes: bool = False, cache_dir: str | Path | None = None,
                 mirror: str | None = None, retries: int = RETRIES, keep_archive: bool = False,
                 confirm: Callable[[str], bool] | None = None, confirm_above: int | None = None,
                 log: Log | None = None, timeout: float | None = None) -> dict:
    """Make ``sample`` (a :class:`~evsmap.samples.Sample` or its name) from its official files.

    The result goes to ``out_root / sample.folder`` (``out_root``: the data root by default). It is
    refused when it exists, unless ``overwrite``. Downloads go to ``cache_dir``
    (:func:`~evsmap.download.default_cache_dir`) and are deleted after a successful fetch unless
    ``keep_archive``; ``mirror`` replaces the base of every URL. Before downloading
    ``confirm_above`` (:data:`CONFIRM_BYTES`) bytes or more, or a large file of unknown size,
    ``confirm(message)`` must answer True unless ``yes``; without ``confirm`` the fetch stops
    with a :class:`~evsmap.download.FetchError` asking for ``--yes``. Returns the manifest written.
    """
    from evsmap.paths import default_data_root

    sample = _resolve(sample)
    say = log or (lambda _msg: None)
    timeout = _download.TIMEOUT if timeout is None else timeout
    target = (Path(out_root) if out_root is not None else default_data_root()) / sample.folder
    empty_folder = target.is_dir() and not any(target.iterdir())
    if target.exists() and not overwrite and not empty_folder:  # the commands' output policy
        raise FetchError(f"{target}: exists (pass --overwrite to replace it)")
    if not sample.sources:
        raise FetchError(f"sample {sample.name!r} has no download source")
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    plans = [_plan(src, cache, source_url(src.url, src.filename, mirror), timeout)
             for src in sample.sources]
    if not yes:
        _confirm(sample, plans, cache, confirm,
                 CONFIRM_BYTES if confirm_above is None else confirm_above)
    for p in plans:
        say(f"using {p.dest} (downloaded earlier)" if p.to_download == 0 else
            f"downloading {p.url} ({format_size(p.size)}) into {cache}")
        # an earlier download is checked again (and fetched anew when it fails)
        _download.download(p.url, p.dest, size=p.size, sha256=p.sha256, retries=retries,
                           timeout=timeout, log=say)
    manifest = _make(sample, plans, target, cache, overwrite, say)
    if not keep_archive:
        for p in plans:
            p.dest.unlink(missing_ok=True)
    return manifest


def _resolve(sample: Sample | str) -> Sample:
    if isinstance(sample, Sample):
        return sample
    if sample not in SAMPLES:
        raise FetchError(f"unknown sample {sample!r} (known: {', '.join(SAMPLES)})")
    return SAMPLES[sample]


def _plan(src: Source, cache: Path, url: str, timeout: float) -> _Plan:
    """What downloading ``src`` from ``url`` into ``cache`` takes: nothing when the file is there
    (of the catalogued size), else the size the catalogue or the server gives, less a ``.part``."""
    dest = cache / src.filename
    if dest.is_file() and (src.size is None or dest.stat().st_size == src.size):
        return _Plan(url, dest, src.size, src.sha256, 0, src.large)
    reported = remote_size(url, timeout=timeout)
    if src.size is not None and reported is not None and reported != src.size:
        raise FetchError(f"{url}: the server reports {reported} bytes, expected {src.size} "
                         "(not the catalogued file)")
    size = src.size if src.size is not None else reported
    part = dest.with_name(dest.name + ".part")
    have = part.stat().st_size if part.is_file() else 0
    return _Plan(url, dest, size, src.sha256, None if size is None else max(size - have, 0),
                 src.large)


def _confirm(sample: Sample, plans: list[_Plan], cache: Path,
             confirm: Callable[[str], bool] | None, threshold: int) -> None:
    """Ask before a download of ``threshold`` bytes or more (or a large one of unknown size)."""
    big = [p for p in plans if p.to_download != 0 and (
        (p.to_download or 0) >= threshold or (p.to_download is None and p.large))]
    if not big:
        return
    first = max(big, key=lambda p: p.to_download or 0)
    what = (f"{format_size(first.to_download)} to download" if first.to_download is not None
            else "a large download of unknown size")
    if confirm is None:
        raise FetchError(f"{first.url}: {what}; pass --yes to go on")
    if not confirm(f"{sample.name}: {what} from {first.url} (into {cache}). Go on?"):
        raise FetchError(f"{first.url}: {what}; not downloaded (pass --yes to go on)")


def _make(sample: Sample, plans: list[_Plan], target: Path, cache: Path, overwrite: bool,
          say: Log) -> dict[str, Any]:
    """Extract the downloads into a staging folder, check them, write the manifest and move the
    sample into place; the manifest."""
    archives = {src.filename: p.dest for src, p in zip(sample.sources, plans, strict=True)}
    records = [{"url": p.url, "file": p.dest.name, "size": p.dest.stat().st_size,
                "sha256": p.sha256.lower() if p.sha256 else  # pooch checked it
                sha256_file(p.dest, desc=f"hashing {p.dest.name}")} for p in plans]
    say(f"extracting {sample.name} into {target}")
    stager = staging_file(target, overwrite=overwrite) if sample.single_file else \
        _staging_folder(target, overwrite)
    with stager as stage, tempfile.TemporaryDirectory(prefix="evsmap-fetch-", dir=_mkdir(cache)) \
            as work:
        try:
            extract_sample(sample, archives, stage, Path(work), log=say)
        except CorruptArchiveError as exc:
            exc.path.unlink(missing_ok=True)
            raise FetchError(f"{exc}; the download was deleted (run the command again to "
                             "download it anew)") from None
        manifest = {
            "format": MANIFEST_FORMAT, "sample": sample.name, "description": sample.description,
            "source": records[0]["url"], "archives": records, "checks": sample.checks,
            "options": dict(sample.options),
            "files": verify_sample(sample, stage, display=target),
            "evsmap_version": evsmap_version(),
            "date": _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat(),
        }
        name = f"{target.name}.{MANIFEST}" if sample.single_file else MANIFEST
        (stage / name).write_text(json.dumps(manifest, indent=2) + "\n")
    return manifest


def _mkdir(path: Path) -> Path:
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FetchError(f"{path}: cannot create the download folder ({exc})") from None
    return path


@contextlib.contextmanager
def _staging_folder(target: Path, overwrite: bool) -> Iterator[Path]:
    from evsmap.fileio import staging_folder

    try:
        with staging_folder(target, overwrite=overwrite) as stage:
            yield stage
    except FetchError:
        raise
    except EvsmapError as exc:
        raise FetchError(str(exc)) from None


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


def summarize(manifest: dict[str, Any]) -> str:
    """One line about a fetched sample: files, bytes, checks."""
    files = manifest.get("files", [])
    total = sum(f.get("size", 0) for f in files)
    checked = sum(1 for f in files if f.get("check") not in (None, "none"))
    return (f"{len(files)} file{'' if len(files) == 1 else 's'}, {format_size(total)}, "
            f"{checked} verified")
