"""What made a folder that a rerun resumes: ``skyfix traverse``'s output (``run.json``) and a
simulated traverse (``simulation.json``).

Both commands keep what an earlier run wrote (the stops already fused, the stops already
rendered) and go on from there, which is right only when the earlier run is the one being
continued. So the parameters that decide the content are recorded in the folder before its first
stop is written; a rerun resumes only when they are the same, and otherwise refuses, naming what
differs (as ``build-db`` does with a store's build parameters). A non-empty folder without the
record is not continued either: written by something else, or by a skyfix that did not record
what made it, it cannot be told apart from another run's.
"""

from __future__ import annotations

import hashlib
import json
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

from .._io import to_json, write_json
from ..errors import OutputExistsError

#: version of the records' layout: a record of another version is another run's
RECORD_VERSION = 1


def digest(obj) -> str:
    """SHA-256 of ``obj`` as canonical JSON (keys sorted, NaN as null)."""
    return hashlib.sha256(to_json(obj).encode()).hexdigest()


def canonical(params: dict) -> dict:
    """``params`` as the record holds them once read back (tuples as lists, NaN as null), so
    that a fresh dict compares equal to the one on disk."""
    return json.loads(to_json(params))


@dataclass(frozen=True)
class Kind:
    """One kind of resumable folder.

    record : the record's file name
    what : a phrase naming the kind in messages ("a traverse output")
    files, folders : what the run writes beside the record: file names, and a regular
        expression of folder names (None: none); what ``--overwrite`` deletes, and nothing else
    legacy : names whose presence without the record marks one written before records existed
    labels : parameter -> its name in messages (the option that sets it), in the order listed
    """

    record: str
    what: str
    files: tuple[str, ...]
    folders: str | None
    legacy: tuple[str, ...]
    labels: dict


def _ours(kind: Kind, name: str) -> bool:
    if name == kind.record or name in kind.files:
        return True
    return kind.folders is not None and re.fullmatch(kind.folders, name) is not None


def _leftover(kind: Kind, name: str) -> bool:
    # the hidden siblings an atomic write (or a staged stop) leaves when killed mid-write: a
    # folder holding nothing else holds nothing worth refusing for
    if not name.startswith("."):
        return False
    rest = name[1:]
    return (any(rest.startswith(f"{f}.") for f in (kind.record, *kind.files))
            or (kind.folders is not None and re.match(rf"(?:{kind.folders})\.", rest) is not None))


def _entries(out: Path, kind: Kind) -> list[str]:
    return sorted(p.name for p in out.iterdir() if not _leftover(kind, p.name))


def _show(v) -> str:
    if isinstance(v, str) and re.fullmatch(r"[0-9a-f]{64}", v):
        return v[:12]
    if isinstance(v, list) and len(v) > 4:
        return f"{len(v)} ({v[0]!r} ... {v[-1]!r})"
    return repr(v)


def differences(old: dict, new: dict, labels: dict) -> list[str]:
    """One phrase per parameter that differs: ``NAME: X there, Y now``."""
    order = list(labels)
    keys = sorted(set(old) | set(new), key=lambda k: (order.index(k) if k in labels else len(order), k))
    return [f"{labels.get(k, k)}: {_show(old.get(k))} there, {_show(new.get(k))} now"
            for k in keys if old.get(k) != new.get(k)]


def plan_folder(out, kind: Kind, params: dict, *, overwrite: bool = False,
                afresh: str | None = "pass --overwrite to start afresh") -> str:
    """What a run with ``params`` may do with the folder ``out``; changes nothing on disk.

    Returns ``new`` (nothing there to keep), ``resume`` (an earlier run with the same
    parameters) or ``replace`` (``overwrite``, and ``out`` was written by this kind of run).
    Refuses a file, a non-empty folder this kind of run did not write (even with ``overwrite``:
    skyfix deletes only what it wrote), one that does not record what made it, and one made with
    other parameters. ``afresh``: how the user starts afresh, offered beside another -o (None:
    the command has no way).
    """
    out = Path(out)
    other = "choose another -o" + (f", or {afresh}" if afresh else "")
    params = canonical(params)
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out} exists and is not a folder: choose another -o")
    if not out.is_dir() or not _entries(out, kind):
        return "new"
    rec = out / kind.record
    if not rec.is_file():
        if any((out / f).exists() for f in kind.legacy):
            if overwrite:
                return "replace"
            raise OutputExistsError(
                f"{out} holds {kind.what} that does not record what made it (no {kind.record}: "
                f"written by an earlier skyfix), so it cannot be resumed safely: {other}")
        raise OutputExistsError(
            f"{out} is not empty and is not {kind.what} (no {kind.record}): choose another -o "
            "(skyfix neither writes into nor deletes a folder it did not write)")
    try:
        old = json.loads(rec.read_text())
        if not isinstance(old, dict) or not isinstance(old.get("params"), dict):
            raise ValueError("no 'params' object")
    except (OSError, UnicodeDecodeError, ValueError) as e:
        if overwrite:
            return "replace"
        raise OutputExistsError(f"{rec} is damaged ({e}): {other}") from None
    if overwrite:
        return "replace"
    if old["params"] != params:
        diffs = differences(old["params"], params, kind.labels)
        raise OutputExistsError(
            f"{out} holds {kind.what} made with other inputs or options ({'; '.join(diffs)}): "
            f"rerun with the same ones to resume it, {'' if afresh else 'or '}{other}")
    return "resume"


def begin_folder(out, kind: Kind, params: dict, action: str, about: dict | None = None) -> None:
    """Carry out :func:`plan_folder`'s ``action`` and record ``params`` (``about``: recorded
    beside them, never compared: where the inputs were, say)."""
    out = Path(out)
    if action == "resume":
        return
    if action == "replace":
        for p in sorted(out.iterdir()):
            if _ours(kind, p.name) or _leftover(kind, p.name):
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p)
                else:
                    p.unlink()
    out.mkdir(parents=True, exist_ok=True)
    # written before the first stop: a run killed at any point leaves a folder a rerun can judge
    write_json(out / kind.record, {"format_version": RECORD_VERSION, "params": canonical(params),
                                   "about": about or {}})
