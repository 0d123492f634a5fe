"""What git says about a checkout: the one place evsmap asks it.

:func:`head_commit` is the commit every record, weights card and gate baseline names (with
``+dirty`` when tracked files have uncommitted changes); the others serve ``evsmap gate
--against``: which commit a file last changed in, what a name resolves to, and a commit's tree
written into a folder.
"""

from __future__ import annotations

import io
import os
import subprocess
import tarfile
from functools import cache
from pathlib import Path

from evsmap.errors import EvsmapError
from evsmap.paths import REPO_ROOT

GIT_TIMEOUT_S = 60


def _git(root: str | os.PathLike[str], *args: str, text: bool = True,
         timeout: float = GIT_TIMEOUT_S) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=text,
                          timeout=timeout, check=False)


def toplevel(path: str | os.PathLike[str]) -> Path | None:
    """The root of the git checkout holding ``path`` (a file or folder), None outside one or
    without git."""
    folder = Path(path)
    folder = folder if folder.is_dir() else folder.parent
    try:
        out = _git(folder, "rev-parse", "--show-toplevel")
    except (OSError, subprocess.SubprocessError):
        return None
    return Path(out.stdout.strip()) if out.returncode == 0 and out.stdout.strip() else None


@cache
def head_commit(root: Path = REPO_ROOT) -> str | None:
    """The commit checked out at ``root`` (evsmap's own checkout by default), ``<sha>+dirty``
    when tracked files have uncommitted changes; None when it is not a checkout or git is
    unavailable."""
    try:
        sha = _git(root, "rev-parse", "HEAD")
        status = _git(root, "status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):
        return None
    if sha.returncode != 0 or not sha.stdout.strip():
        return None
    return sha.stdout.strip() + ("+dirty" if status.stdout.strip() else "")


def resolve_commit(root: Path, ref: str) -> str:
    """The full sha of ``ref`` (a commit, branch or tag) in the checkout at ``root``.

    Raises:
        EvsmapError: ``ref`` names no commit there (a shallow clone is named as the likely
            cause, with how to deepen it).
    """
    try:
        out = _git(root, "rev-parse", "--verify", "--quiet", f"{ref}^{{commit}}")
        shallow = _git(root, "rev-parse", "--is-shallow-repository").stdout.strip() == "true"
    except (OSError, subprocess.SubprocessError) as exc:
        raise EvsmapError(f"--against {ref}: cannot run git in {root} ({exc})") from None
    if out.returncode != 0 or not out.stdout.strip():
        hint = (" (this clone is shallow: fetch the history, e.g. `git fetch --unshallow` or "
                "`fetch-depth: 0` in GitHub Actions)" if shallow else "")
        raise EvsmapError(f"--against {ref}: no such commit, branch or tag in {root}{hint}")
    return out.stdout.strip()


def last_commit_of(path: str | os.PathLike[str]) -> str | None:
    """The commit that last changed the committed ``path``; None when it was never committed
    (or git is unavailable)."""
    path = Path(path).resolve()
    root = toplevel(path)
    if root is None:
        return None
    try:
        out = _git(root, "log", "-1", "--format=%H", "--", str(path.relative_to(root)))
    except (OSError, subprocess.SubprocessError, ValueError):
        return None
    return out.stdout.strip() or None


def is_shallow_boundary(root: Path, commit: str) -> bool:
    """Whether ``commit`` is where a shallow clone's history was cut (its parents are missing,
    so ``git log`` takes it for the commit that made every file it holds)."""
    try:
        out = _git(root, "rev-parse", "--git-path", "shallow")
    except (OSError, subprocess.SubprocessError):
        return False
    path = Path(out.stdout.strip())
    path = path if path.is_absolute() else root / path
    try:
        return commit in path.read_text().split()
    except OSError:
        return False


def export_tree(root: Path, commit: str, dest: Path) -> None:
    """Write the files of ``commit`` (as ``git archive`` gives them) into ``dest``: a checkout
    that leaves the repository's own state untouched.

    Raises:
        EvsmapError: git could not produce the tree.
    """
    try:
        out = _git(root, "archive", "--format=tar", commit, text=False, timeout=600)
    except (OSError, subprocess.SubprocessError) as exc:
        raise EvsmapError(f"cannot export commit {commit[:12]} from {root}: {exc}") from None
    if out.returncode != 0:
        why = out.stderr.decode(errors="replace").strip().splitlines()[-1:] or ["git failed"]
        raise EvsmapError(f"cannot export commit {commit[:12]} from {root}: {why[0]}")
    dest.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(out.stdout)) as tar:
        tar.extractall(dest, filter="data")
