"""Small I/O helpers shared by the stages: atomic writes, output checks and JSON that tolerates NaN.

Every output goes through :func:`atomic_path` (a crash never leaves half a file that looks
whole); the CLI checks every output with :func:`check_outputs` before any work, so a bad path
fails at once rather than after a long search, and never after another output was written.
A file output whose folder does not exist is refused (as ``cp`` or a shell redirect would):
skyfix creates only the folders it is asked to create (``build-db -o``, ``simulate --out``,
``evaluate --out``, ``demo --out``), never a folder for a file, so a mistyped path fails loudly
instead of leaving a stray folder tree.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .errors import OutputExistsError, SkyfixError

_UMASK = os.umask(0)
os.umask(_UMASK)

#: suffix -> matplotlib format of the figures skyfix can draw (``--plot``); these need no
#: optional backend, and naming one is enough to choose it.
PLOT_FORMATS = {".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg", ".pdf": "pdf", ".svg": "svg"}
#: suffixes of a GeoTIFF output (``locate --score-map``)
GEOTIFF_SUFFIXES = (".tif", ".tiff")


def cannot_write(path, reason: str) -> SkyfixError:
    """The one error for an output that cannot be written: ``cannot write PATH: REASON``."""
    return SkyfixError(f"cannot write {path}: {reason}")


def _reason(e: OSError) -> str:
    """What the OS said, without Python's ``[Errno n]`` prefix and the file name repeated."""
    return (e.strerror or str(e)).strip()


def _nearest_existing(path: Path) -> Path:
    """``path`` or its nearest ancestor that exists (the current folder for a relative path)."""
    p = path
    while not os.path.lexists(p):
        if p.parent == p:
            break
        p = p.parent
    return p


def _file_in_the_way(path: Path) -> Path | None:
    """``path`` or its nearest existing ancestor when that is a file, not a folder, else None."""
    anc = _nearest_existing(path)
    return anc if os.path.lexists(anc) and not anc.is_dir() else None


def check_folder_output(path) -> Path:
    """Refuse, before any work, a folder output (created with its parents) whose path runs
    through a file: the failure would come late and name a temporary folder."""
    path = Path(path)
    blocker = _file_in_the_way(path)
    if blocker is not None:
        raise cannot_write(path, f"{blocker} is a file, not a folder")
    kernel = _on_kernel_file_system(path)
    if kernel is not None:  # said now: creating it fails late, naming a staging folder
        raise cannot_write(path, kernel)
    return path


@contextmanager
def writing_to(out):
    """Turn an operating-system error while writing the folder output ``out`` (a read-only place,
    a parent that is a file, a full disk) into a one-line error instead of a traceback.

    An error naming a file elsewhere (reading the DEM, say) is not about ``out`` and passes on.
    """
    try:
        yield
    except OSError as e:
        if e.filename is not None and not _concerns(Path(e.filename), Path(out)):
            raise
        reason = _reason(e)
        where = f" ({e.filename})" if e.filename and str(e.filename) != str(out) else ""
        # mkdir under a file says "File exists" or "Not a directory": name the file instead
        blocker = _file_in_the_way(Path(out).parent)
        if blocker is not None:
            reason, where = f"{blocker} is a file, not a folder", ""
        kernel = _on_kernel_file_system(Path(out).parent)
        if kernel is not None:  # /proc says "No such file or directory": not the reason
            reason, where = kernel, ""
        raise cannot_write(out, f"{reason}{where}; choose another --out") from None


def _concerns(path: Path, out: Path) -> bool:
    """Whether ``path`` is ``out``, inside it, one of its parents, or a staging sibling of it."""
    path, out = path.resolve(), out.resolve()
    if path == out or out in path.parents or path in out.parents:
        return True
    # the simulator renders into a hidden sibling (.NAME.xxx.partial) before it takes out's place
    return out.parent in path.parents and path.relative_to(out.parent).parts[0].startswith(f".{out.name}.")


def _missing_folder_reason(path: Path) -> str | None:
    """Why the folder that would hold ``path`` is unusable, or None when it is a folder."""
    parent = path.parent
    if parent.is_dir():
        return None
    blocker = _file_in_the_way(parent)
    if blocker is not None:
        return f"{blocker} is a file, not a folder"
    return f"folder {parent} does not exist (create it first, or give another path)"


#: file systems the kernel serves, which hold no files of a user's: writing into /proc says "No
#: such file or directory", into /sys "Permission denied" (as root too), neither the real reason
KERNEL_FILE_SYSTEMS = {"proc", "sysfs", "cgroup", "cgroup2", "debugfs", "tracefs", "securityfs",
                       "pstore", "bpf", "configfs", "fusectl", "devpts", "mqueue", "binfmt_misc",
                       "efivarfs", "autofs", "nsfs"}


def _file_system_type(folder: Path) -> str | None:
    """The type of the file system ``folder`` lies on (Linux, from /proc/self/mounts); None
    where that cannot be read."""
    try:
        mounts = Path("/proc/self/mounts").read_text().splitlines()
    except OSError:
        return None
    where = os.path.realpath(folder)
    best, kind = "", None
    for line in mounts:
        fields = line.split()
        if len(fields) < 3:
            continue
        point = fields[1].replace("\\040", " ")
        inside = where == point or where.startswith(point.rstrip("/") + "/")
        if inside and len(point) >= len(best):
            best, kind = point, fields[2]
    return kind


def _unwritable(folder: Path, e: OSError) -> str:
    """Why no file can be created in the existing ``folder``, ``e`` the OS's answer."""
    kind = _file_system_type(folder)
    if kind in KERNEL_FILE_SYSTEMS:
        return _kernel_file_system(folder, kind)
    return f"folder {folder} is not writable ({_reason(e)})"


def _on_kernel_file_system(path: Path) -> str | None:
    """Why nothing can be created at ``path`` when its nearest existing folder lies on a file
    system the kernel serves (/proc, /sys), else None."""
    anc = _nearest_existing(path)
    kind = _file_system_type(anc) if anc.is_dir() else None
    return _kernel_file_system(anc, kind) if kind in KERNEL_FILE_SYSTEMS else None


def _kernel_file_system(folder: Path, kind: str) -> str:
    return (f"folder {folder} is on the kernel's {kind} file system, which holds no files of "
            "yours: give a folder on a disk")


def check_staging_writable(path) -> None:
    """Refuse (``cannot write PATH``) a folder output ``path`` that is staged beside itself and
    renamed into place, when no file can be created there: in the nearest existing folder above
    it. Checked before an --overwrite deletes what was there (a store deleted, then the new one
    refused by a folder the user cannot write, left nothing)."""
    p = Path(path).absolute().parent
    while not p.exists() and p != p.parent:
        p = p.parent
    if not p.is_dir():
        raise cannot_write(path, f"{p} is a file, not a folder")
    _probe_folder(p, path)


def _probe_folder(folder: Path, path) -> None:
    """Create and delete a temporary file in ``folder``: the one reliable test that ``path`` can
    be written there (permissions, a read-only file system, root's exemptions, ACLs)."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=".skyfix-write-test.", dir=folder)
    except OSError as e:
        raise cannot_write(path, _unwritable(folder, e)) from None
    os.close(fd)
    os.unlink(tmp)


@contextmanager
def atomic_path(path, *, suffix: str | None = None):
    """Yield a temporary path beside ``path``; rename it onto ``path`` only if the block succeeds.

    A crash never leaves half a file that looks whole. Missing folders are created (library
    callers write into folders they own; the CLI refuses a missing folder up front with
    :func:`check_can_write`). Any OS error writing ``path`` becomes one :class:`SkyfixError`,
    ``cannot write PATH: REASON``.
    """
    path = Path(path)
    if path.is_dir():
        raise cannot_write(path, "it is a folder (give a file name)")
    if path.is_symlink():  # the link stays; what it points at is replaced, as a shell's > would
        path = Path(os.path.realpath(path))
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(
            prefix=f".{path.name}.", suffix=suffix or path.suffix or ".tmp", dir=path.parent
        )
    except OSError as e:
        raise cannot_write(path, _missing_folder_reason(path) or _unwritable(path.parent, e)) from None
    os.close(fd)
    try:
        try:
            yield Path(tmp)
        except OSError as e:
            # An OS error about the temporary file (disk full, quota) is a failure to write
            # ``path``; any other OS error in the block is the block's own and passes through.
            if e.filename not in (None, tmp, str(tmp)):
                raise
            raise cannot_write(path, _reason(e)) from None
        try:
            # mkstemp makes the file private (0600); give it the mode a plain open() would have
            os.chmod(tmp, 0o666 & ~_UMASK)
            os.replace(tmp, path)
        except OSError as e:
            raise cannot_write(path, _reason(e)) from None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _clean(obj):
    """Make ``obj`` JSON-serialisable: numpy scalars/arrays to Python, NaN/inf to None."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, Path):
        return str(obj)
    return obj


def to_json(obj, *, indent: int | None = None) -> str:
    """JSON text of ``obj`` with NaN and infinities written as ``null``."""
    return json.dumps(_clean(obj), indent=indent, allow_nan=False)


def write_json(path, obj, *, indent: int | None = 1) -> Path:
    """Atomically write ``obj`` as JSON to ``path``."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(to_json(obj, indent=indent) + "\n")
    return path


def write_jsonl(path, rows) -> Path:
    """Atomically write ``rows`` to ``path`` as JSON lines (NaN and infinities as ``null``)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text("".join(to_json(r) + "\n" for r in rows))
    return path


def save_figure(fig, path, **savefig_kw) -> Path:
    """Atomically write a matplotlib figure in the format its suffix names (see PLOT_FORMATS)."""
    path = Path(path)
    fmt = PLOT_FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise cannot_write(path, _suffix_reason(path, PLOT_FORMATS))
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=fmt, **savefig_kw)
    return path


def _suffix_reason(path: Path, suffixes) -> str:
    named = f"the suffix {path.suffix!r}" if path.suffix else "no suffix"
    return f"{named} names no format it can be written in: end it with {', '.join(suffixes)}"


def check_can_write(path, overwrite: bool, *, folder: bool | None = None, suffixes=None) -> Path:
    """Refuse, before any work, an output ``path`` that could not be written.

    Refuses an existing ``path`` unless ``overwrite``; with ``folder=False`` (a file output) an
    existing folder at ``path``; a missing or unwritable folder to hold it; and, with
    ``suffixes``, a suffix not among them. ``folder=None`` keeps the old meaning for callers
    whose output may be either (an existing folder is then "already exists").
    """
    path = Path(path)
    if folder is False and path.is_dir():
        raise cannot_write(path, "it is a folder: give a file name" +
                           (f", e.g. {path / 'out'}{next(iter(suffixes))}" if suffixes else ""))
    if str(path) == "-":
        raise cannot_write(path, "skyfix writes its outputs to files, not to standard output: "
                                 "give a file name")
    if suffixes is not None and path.suffix.lower() not in suffixes:
        raise cannot_write(path, _suffix_reason(path, suffixes))
    if path.exists() and not (path.is_file() or path.is_dir()):
        # a device, a pipe or a socket cannot be replaced by a file written whole, and must not be
        raise cannot_write(path, "it is not a regular file (a device, pipe or socket): give a "
                                 "file name")
    if os.path.lexists(path) and not overwrite:
        raise OutputExistsError(f"{path} already exists: pass --overwrite to replace it")
    if folder is True and path.is_dir():
        _probe_folder(path, path)
        return path
    reason = _missing_folder_reason(path)
    if reason is not None:
        raise cannot_write(path, reason)
    _probe_folder(path.parent, path)
    return path


def check_not_inputs(outputs, inputs) -> None:
    """Refuse an output that is one of the command's input files (links and relative paths
    resolved): ``--overwrite`` would otherwise replace an image or a DEM with the answer.

    outputs : ``(option, path, ...)`` tuples, ``path`` None = not asked for; inputs : paths
    """
    ins = {os.path.realpath(p) for p in inputs if p is not None}
    for option, path, *_ in outputs:
        if path is not None and os.path.realpath(path) in ins:
            raise SkyfixError(f"{option} {path} is one of this command's inputs: writing it would "
                              "destroy it; give the output another name")


def check_outputs(overwrite: bool, *outputs, inputs=()) -> None:
    """Check every output of one command before any work (see :func:`check_can_write`).

    outputs : ``(option, path, suffixes)`` for each file output; ``path`` None = not asked for,
        ``suffixes`` None = any. Two options naming the same file are refused too: the second
        would silently replace the first; so is one that names a file of ``inputs``
        (:func:`check_not_inputs`).
    """
    check_not_inputs(outputs, inputs)
    seen: dict[str, str] = {}
    for option, path, suffixes in outputs:
        if path is None:
            continue
        check_can_write(path, overwrite, folder=False, suffixes=suffixes)
        if suffixes is PLOT_FORMATS:  # a figure: refused now, not after the work, if it cannot be drawn
            from .optional import require

            require("matplotlib", f"{option} (a figure)")
        key = os.path.normcase(os.path.abspath(path))
        if key in seen:
            raise SkyfixError(f"{seen[key]} and {option} both name {path}: give each output its own file")
        seen[key] = option
