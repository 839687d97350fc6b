"""The simulator's output folder, replaced whole: rendered into a hidden sibling that takes the
place of ``--out`` only when complete (an atomic renameat2 exchange where the filesystem has
one, else two renames that keep the old folder until the last moment).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import contextmanager
from glob import escape as glob_escape
from pathlib import Path

from ..errors import OutputExistsError, ParameterError


def check_not_current(out) -> None:
    """Refuse an ``out`` that is the current folder or one holding it: the output is rendered
    beside ``out`` and swapped into its place, and ``-o .`` rendered into itself and was refused
    only after the rendering (or, with --overwrite, could not be swapped)."""
    o, cwd = Path(out).resolve(), Path.cwd().resolve()
    if o == cwd or o in cwd.parents:
        raise ParameterError(f"--out {out} is the current folder or holds it: the output replaces "
                             "--out whole; give a folder of its own, e.g. -o sim")


def check_out_folder(out, overwrite: bool) -> Path:
    """Refuse an ``out`` that is a file, or a non-empty folder without ``overwrite``; touch nothing.
    Returns it resolved: a symbolic link's target is what gets replaced (the link kept), not the
    link (swapped for a folder, and its old target left as a stray hidden link)."""
    check_not_current(out)
    out = Path(out).resolve()
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out} exists and is not a folder: choose another --out")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise OutputExistsError(f"{out} is not empty: pass --overwrite to replace it")
    return out


_UMASK = os.umask(0)
os.umask(_UMASK)


#: renameat2(2) flag that swaps two paths in one step (Linux >= 3.15, most local filesystems)
_RENAME_EXCHANGE = 2


def _exchange(a: Path, b: Path) -> bool:
    """Swap the two existing paths ``a`` and ``b`` atomically; False where the system cannot."""
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd = -100  # paths relative to the current folder, as os.rename takes them
    return renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE) == 0


def _replace_folder(new: Path, out: Path) -> None:
    """Put the finished folder ``new`` in the place of ``out`` (which may exist).

    An atomic exchange where the filesystem offers one; else two renames, during which the old
    folder is kept beside ``out`` and put back if the second fails: never a moment where the old
    content is gone and the new one not yet in place.
    """
    if not out.exists():
        os.rename(new, out)
        return
    if _exchange(new, out):
        shutil.rmtree(new)  # holds the old content now
        return
    old = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
    os.rmdir(old)
    os.rename(out, old)
    try:
        os.rename(new, out)
    except BaseException:
        os.rename(old, out)
        raise
    shutil.rmtree(old)


@contextmanager
def staged_folder(out, overwrite: bool):
    """Yield an empty hidden sibling of ``out`` to render into; it replaces ``out`` only when the
    block succeeds, so a failure or a kill leaves any earlier ``out`` as it was."""
    out = check_out_folder(out, overwrite)
    out.parent.mkdir(parents=True, exist_ok=True)
    # what a killed run of the same output left half-rendered (never an ``.old``: that can be the
    # earlier output itself, moved aside by a run killed while swapping folders)
    for stale in out.parent.glob(f".{glob_escape(out.name)}.*.partial"):
        if stale.is_dir() and not stale.is_symlink():
            shutil.rmtree(stale, ignore_errors=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=out.parent))
    try:
        yield tmp
        os.chmod(tmp, 0o777 & ~_UMASK)  # mkdtemp makes it private; give it a plain mkdir's mode
        check_out_folder(out, overwrite)  # something may have appeared there meanwhile
        _replace_folder(tmp, out)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
