"""Small I/O helpers shared by the stages: atomic writes and JSON that tolerates NaN."""

from __future__ import annotations

import json
import math
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .errors import OutputExistsError


_UMASK = os.umask(0)
os.umask(_UMASK)


@contextmanager
def atomic_path(path, *, suffix: str | None = None):
    """Yield a temporary path beside ``path``; rename it onto ``path`` only if the block succeeds.

    A crash never leaves half a file that looks whole.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(
        prefix=f".{path.name}.", suffix=suffix or path.suffix or ".tmp", dir=path.parent
    )
    os.close(fd)
    try:
        yield Path(tmp)
        # mkstemp makes the file private (0600); give it the mode a plain open() would have
        os.chmod(tmp, 0o666 & ~_UMASK)
        os.replace(tmp, path)
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


def check_can_write(path, overwrite: bool) -> Path:
    """Refuse to replace an existing ``path`` unless ``overwrite``."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise OutputExistsError(f"{path} already exists: pass --overwrite to replace it")
    return path
