"""Simulated inputs a benchmark keeps between runs, reused only for the settings they were made
with: a rerun with another seed or world scored the images kept from the first against a truth
drawn anew, and printed the new settings over them."""

from __future__ import annotations

import json
from pathlib import Path


def check_reuse(path, settings: dict, made: bool) -> None:
    """Refuse (SystemExit) to reuse inputs unless the settings file ``path`` says they were made
    with ``settings`` (a JSON-able dict of what shaped them); ``made``: whether inputs are there
    already. :func:`record` writes the file once new inputs are made."""
    path = Path(path)
    if not made:
        return
    if not path.is_file():
        raise SystemExit(f"{path.parent} holds inputs made before their settings were recorded "
                         f"({path.name}): remove them, or give another output folder")
    kept = json.loads(path.read_text())
    want = json.loads(json.dumps(settings))  # tuples as lists, as they were written
    diff = {k: (kept.get(k), want.get(k)) for k in set(kept) | set(want) if kept.get(k) != want.get(k)}
    if diff:
        raise SystemExit(f"the inputs in {path.parent} were made with other settings ("
                         + ", ".join(f"{k} {a!r} there, {b!r} now" for k, (a, b) in sorted(diff.items()))
                         + "): give another output folder, or remove them")


def record(path, settings: dict) -> None:
    """Write the settings file ``path`` of inputs made with ``settings``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(settings, indent=1))
