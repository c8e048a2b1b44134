"""The version of idstlpy and the commit of the checkout it runs from.

The version is written here and only here: ``pyproject.toml`` reads it (``[tool.hatch.version]``),
so the package metadata (``importlib.metadata.version("idstlpy")``), ``idstlpy.__version__``,
``idstlpy --version`` and every result file agree. It follows semantic versioning
(MAJOR.MINOR.PATCH; while MAJOR is 0, a MINOR step may change the API or the results); every
change is listed in ``CHANGELOG.md``.

The commit is read from the checkout's ``.git`` directory without running git (a worktree's
``.git`` file, loose and packed references are followed); it is ``None`` when the package is not
run from a git checkout (an installed wheel) or the metadata cannot be read. A checkout with
uncommitted changes reports its ``HEAD`` commit: the commit says which code a result came from
only for a clean checkout.
"""

from __future__ import annotations

import functools
import platform
import re
import sys
from pathlib import Path

__all__ = ["__version__", "git_commit", "software_info"]

__version__ = "0.2.0"

_SHA = re.compile(r"^[0-9a-f]{40}([0-9a-f]{24})?$")


def _read(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError):
        return None


def _git_dir(root: Path) -> Path | None:
    """The git directory of the checkout at ``root`` (following a worktree's ``.git`` file)."""
    dot_git = root / ".git"
    if dot_git.is_dir():
        return dot_git
    text = _read(dot_git) if dot_git.is_file() else None
    if text is None or not text.startswith("gitdir:"):
        return None
    target = Path(text[len("gitdir:") :].strip())
    return target if target.is_absolute() else (root / target)


def _resolve_ref(git_dir: Path, ref: str) -> str | None:
    """The commit a reference (``refs/heads/main``) names, in the loose or the packed refs."""
    common_text = _read(git_dir / "commondir")
    common = git_dir if common_text is None else (git_dir / common_text)
    for base in (git_dir, common):
        sha = _read(base / ref)
        if sha is not None and _SHA.match(sha):
            return sha
    packed = _read(common / "packed-refs")
    if packed is not None:
        for line in packed.splitlines():
            parts = line.split()
            if len(parts) == 2 and parts[1] == ref and _SHA.match(parts[0]):
                return parts[0]
    return None


def git_commit(root: str | Path | None = None) -> str | None:
    """The commit checked out at ``root``, read from its git metadata (git itself is not run).

    Parameters
    ----------
    root : str or Path, optional
        A checkout's top directory; by default the one this package is imported from (two
        levels above the package: ``<root>/src/idstlpy``), provided it holds the
        ``pyproject.toml`` of idstlpy.

    Returns
    -------
    str or None
        The 40 (or 64) hex digits of ``HEAD``; ``None`` when ``root`` is not a git checkout of
        idstlpy or its metadata cannot be read (never raises).
    """
    try:
        if root is None:
            top = Path(__file__).resolve().parents[2]
            pyproject = _read(top / "pyproject.toml")
            if pyproject is None or 'name = "idstlpy"' not in pyproject:
                return None
        else:
            top = Path(root)
        git_dir = _git_dir(top)
        if git_dir is None:
            return None
        head = _read(git_dir / "HEAD")
        if head is None:
            return None
        if _SHA.match(head):  # a detached HEAD
            return head
        if head.startswith("ref:"):
            return _resolve_ref(git_dir, head[len("ref:") :].strip())
    except (OSError, ValueError, IndexError):
        return None
    return None


@functools.cache
def _commit_of_this_checkout() -> str | None:
    return git_commit()


def software_info() -> dict[str, str | None]:
    """Which code made a result: the versions of idstlpy, Python and NumPy, the platform, the commit.

    Returns
    -------
    dict
        ``{"idstlpy": "0.2.0", "commit": "<40 hex digits>" or None, "python": "3.11.7",
        "numpy": "2.4.6", "platform": "linux"}``. The commit is read once per process.
    """
    import numpy as np

    return {
        "idstlpy": __version__,
        "commit": _commit_of_this_checkout(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "platform": sys.platform,
    }
