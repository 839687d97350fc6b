"""The package's walls: no import circle between its modules, no private name used across them.

Read from the source with :mod:`ast`, so the check covers imports inside functions too (a lazy
import still ties two modules together). A module is a ``.py`` file; a package's
``__init__.py`` is the package. ``skyfix._io`` is a private *module* of the package, which its
siblings may use; what may not cross a module boundary is a private *name* (``_helper``)
defined in one module and used in another.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PACKAGE = "skyfix"


def _module_name(path: Path, src: Path) -> str:
    parts = list(path.relative_to(src).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _modules(src: Path = SRC) -> dict[str, Path]:
    return {_module_name(p, src): p for p in sorted((src / PACKAGE).rglob("*.py"))}


def _is_package(path: Path) -> bool:
    return path.name == "__init__.py"


def _resolve(importer: str, importer_path: Path, level: int, module: str | None) -> str:
    """The absolute name of ``from <level dots><module> import ...`` written in ``importer``."""
    if level == 0:
        return module or ""
    base = importer.split(".")
    if not _is_package(importer_path):
        base = base[:-1]
    base = base[: len(base) - (level - 1)]
    return ".".join(base + ([module] if module else []))


def _is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _imports(mods: dict[str, Path]):
    """Yield (importer, imported module, names taken from it, attribute names used on it, line)."""
    for name, path in mods.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        aliases: dict[str, str] = {}  # local name -> module it refers to
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                target = _resolve(name, path, node.level, node.module)
                if not target.startswith(PACKAGE):
                    continue
                for a in node.names:
                    sub = f"{target}.{a.name}"
                    if sub in mods:  # `from . import match`: the module itself
                        aliases[a.asname or a.name] = sub
                        yield name, sub, [], node.lineno
                    else:
                        yield name, target, [a.name], node.lineno
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith(PACKAGE):
                        if a.asname:
                            aliases[a.asname] = a.name
                        yield name, a.name, [], node.lineno
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id in aliases and _is_private(node.attr)):
                yield name, aliases[node.value.id], [node.attr], node.lineno


def _graph(mods):
    edges: dict[str, set[str]] = {m: set() for m in mods}
    for importer, target, _names, _line in _imports(mods):
        if target in mods and target != importer:
            edges[importer].add(target)
    return edges


def _cycles(edges) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in edges:
        if v not in index:
            visit(v)
    return out


def _package_of(mod: str, mods) -> str:
    return mod if _is_package(mods[mod]) else mod.rpartition(".")[0]


def test_no_import_circle():
    mods = _modules()
    edges = _graph(mods)
    # A submodule that imports its own package's __init__ (which re-exports from the submodule)
    # is a circle in the source even when Python tolerates it at run time.
    cycles = _cycles(edges)
    assert not cycles, "import circles between modules: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_no_import_circle_between_stages():
    """The stages (``skyfix.X``: a module or a whole sub-package) import each other in one
    direction only: ``figures`` drawing a traverse while ``traverse`` drew with ``figures`` was a
    circle no module-level check saw."""
    mods = _modules()
    stage = {m: m.split(".")[1] if m.count(".") >= 1 else m for m in mods}
    edges: dict[str, set[str]] = {s: set() for s in stage.values()}
    for importer, target, _names, _line in _imports(mods):
        if target in mods and stage[target] != stage[importer]:
            edges[stage[importer]].add(stage[target])
    cycles = _cycles(edges)
    assert not cycles, "import circles between stages: " + "; ".join(" <-> ".join(c) for c in cycles)


def test_no_private_name_crosses_a_module_boundary():
    mods = _modules()
    crossings = []
    for importer, target, names, line in _imports(mods):
        for n in names:
            if _is_private(n) and target != importer:
                crossings.append(f"{mods[importer].relative_to(SRC)}:{line} uses {target}.{n}")
    assert not crossings, "private names used across modules:\n" + "\n".join(crossings)


def test_the_checks_catch_what_they_look_for(tmp_path):
    """The two checks above on a toy package that breaks both rules (so they can fail)."""
    pkg = tmp_path / PACKAGE
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from .b import _helper\n")
    (pkg / "b.py").write_text("def _helper():\n    from . import a\n    return a._x\n")
    mods = _modules(tmp_path)
    assert _cycles(_graph(mods)) == [["skyfix.a", "skyfix.b"]]
    private = sorted((i, t, n) for i, t, ns, _ in _imports(mods) for n in ns if _is_private(n))
    assert private == [("skyfix.a", "skyfix.b", "_helper"), ("skyfix.b", "skyfix.a", "_x")]


LIMIT_LINES = 500
#: modules allowed past LIMIT_LINES because they hold one idea; say why beside each
ONE_IDEA = {
}


@pytest.mark.parametrize("mod", sorted(_modules()))
def test_modules_stay_small(mod):
    path = _modules()[mod]
    n = len(path.read_text().splitlines())
    assert n <= LIMIT_LINES or mod in ONE_IDEA, f"{path.relative_to(SRC)} has {n} lines"
