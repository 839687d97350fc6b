"""Print who imports whom between skyfix's stages (modules and sub-packages), read from the source
with the same analysis as ``tests/test_architecture.py`` (lazy imports inside functions count).

    python scripts/import_graph.py            # the stage graph, as in docs/architecture.md
    python scripts/import_graph.py --files    # every module with its line count
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import test_architecture as arch  # noqa: E402


def stage(module: str) -> str:
    """``skyfix.detect.dp`` -> ``detect``; ``skyfix`` (the package's own __init__) -> ``skyfix``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--files", action="store_true")
    args = ap.parse_args(argv)
    mods = arch._modules()
    if args.files:
        for m, p in sorted(mods.items()):
            print(f"{m:36s} {len(p.read_text().splitlines()):5d}")
        return
    deps: dict[str, set[str]] = {}
    for a, targets in arch._graph(mods).items():
        for b in targets:
            if stage(a) != stage(b) and stage(b) != "skyfix":
                deps.setdefault(stage(a), set()).add(stage(b))
    for s in sorted(deps):
        print(f"{s:10s} -> {', '.join(sorted(deps[s]))}")


if __name__ == "__main__":
    main()
