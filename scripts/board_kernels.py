"""The board commands' numba kernels compiled ahead of time (see ``skyfix.jit``).

    python scripts/board_kernels.py record TYPES.json -- locate ACQ --db DB --dem DEM -o F
    python scripts/board_kernels.py build [--types TYPES.json] [--out DIR]

``record`` runs one skyfix command in this process with numba's JIT and merges the argument and
return types every kernel was compiled for into TYPES.json (created if absent). The shipped
record, ``src/skyfix/board_kernels.json``, was made by running it on each command of
``benchmarks/bench_board.py`` (``locate`` and ``heading`` on its three acquisitions) and on
``skyfix detect`` of a grey image and an Earth photo, ``skyfix profile`` and ``skyfix attitude``.

``build`` compiles every recorded signature with numba's ``pycc`` into one extension module,
``_board_kernels``, and writes its table of exports and argument types beside it: by default into
the installed ``skyfix`` package, which makes the board commands run without loading numba
(``scripts/board_install.sh`` does this). It needs numba and a C compiler, on the ground only.
The table goes first and is written last, so an interrupted build leaves a package that runs on
numba's JIT.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

# --- numba types <-> JSON ---------------------------------------------------------------------

def encode(t):
    """A numba type as JSON, or None where it is not one a kernel's export can take."""
    from numba.core import types

    if isinstance(t, types.Array):
        if not t.aligned or t.dtype.name not in _NUMPY:
            return None
        return ["array", t.dtype.name, t.ndim, t.layout, not t.mutable]
    if isinstance(t, types.Boolean):
        return ["scalar", "bool"]
    if isinstance(t, (types.Integer, types.Float)) and not isinstance(t, types.Literal):
        return ["scalar", t.name]
    if isinstance(t, types.UniTuple):
        inner = encode(t.dtype)
        return None if inner is None else ["unituple", inner, t.count]
    if isinstance(t, types.Tuple):
        inner = [encode(x) for x in t.types]
        return None if any(x is None for x in inner) else ["tuple", inner]
    if isinstance(t, types.NoneType):
        return ["none"]
    return None


_NUMPY = {"float32", "float64", "int8", "int16", "int32", "int64", "uint8", "uint16", "uint32",
          "uint64", "bool"}


def decode(spec):
    from numba.core import types

    kind = spec[0]
    if kind == "array":
        _, dtype, ndim, layout, readonly = spec
        return types.Array(_scalar(dtype), ndim, layout, readonly=readonly)
    if kind == "scalar":
        return _scalar(spec[1])
    if kind == "unituple":
        return types.UniTuple(decode(spec[1]), spec[2])
    if kind == "tuple":
        return types.Tuple([decode(x) for x in spec[1]])
    if kind == "none":
        return types.none
    raise ValueError(f"unknown type spec {spec!r}")


def _scalar(name):
    from numba.core import types

    return types.boolean if name == "bool" else getattr(types, name)


# --- record -----------------------------------------------------------------------------------

def record(types_path: Path, command: list[str]) -> None:
    os.environ["SKYFIX_JIT"] = "1"  # the dispatchers, not a build already installed
    from skyfix import jit
    from skyfix.cli.main import cli

    try:
        cli.main(command, standalone_mode=False)
    except SystemExit as e:
        if e.code not in (0, None):
            raise
    old = json.loads(types_path.read_text()) if types_path.exists() else {"kernels": []}
    by_key = {(k["module"], k["name"]): k for k in old["kernels"]}
    added = 0
    for disp in jit.registered():
        f = disp.py_func
        entry = by_key.setdefault((f.__module__, f.__qualname__),
                                  {"module": f.__module__, "name": f.__qualname__, "signatures": []})
        for sig in disp.nopython_signatures:
            args = [encode(a) for a in sig.args]
            ret = encode(sig.return_type)
            if ret is None or any(a is None for a in args):
                print(f"record: {f.__qualname__}{sig} has a type pycc cannot export; left to the JIT",
                      file=sys.stderr)
                continue
            rec = {"args": args, "return": ret}
            if rec not in entry["signatures"]:
                entry["signatures"].append(rec)
                added += 1
    kernels = sorted((k for k in by_key.values() if k["signatures"]),
                     key=lambda k: (k["module"], k["name"]))
    tmp = types_path.with_name(types_path.name + ".tmp")
    tmp.write_text(json.dumps({"kernels": kernels}, indent=1) + "\n")
    tmp.replace(types_path)
    print(f"record: {added} new signatures, {sum(len(k['signatures']) for k in kernels)} in "
          f"{len(kernels)} kernels -> {types_path}", file=sys.stderr)


# --- build ------------------------------------------------------------------------------------

def build(types_path: Path, out: Path | None, cpu: str = "host") -> None:
    os.environ["SKYFIX_JIT"] = "1"
    from numba.core import typing
    from numba.pycc import CC

    from skyfix import jit

    if out is None:
        import skyfix

        out = Path(skyfix.__file__).resolve().parent
    kernels = json.loads(types_path.read_text())["kernels"]
    out.mkdir(parents=True, exist_ok=True)
    cc = CC(jit.MODULE)
    # pycc's default is a generic x86-64 (portable, no AVX): the rover's own CPU is what counts
    if cpu == "host":
        import llvmlite.binding as llvm

        cpu = llvm.get_host_cpu_name()
    cc.target_cpu = "" if cpu == "generic" else cpu
    table = {}
    n = 0
    for k in kernels:
        disp = getattr(importlib.import_module(k["module"]), k["name"].split(".")[-1])
        name = jit.export_name(disp.py_func)
        rows = table.setdefault(name, [])
        for i, sig in enumerate(k["signatures"]):
            export = f"{name}__{i}"
            s = typing.signature(decode(sig["return"]), *[decode(a) for a in sig["args"]])
            cc.export(export, s)(disp.py_func)
            rows.append([export, sig["args"]])
            n += 1
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        cc.output_dir = tmp
        cc.compile()
        built = [p for p in Path(tmp).iterdir() if p.name.startswith(jit.MODULE + ".")]
        if len(built) != 1:
            raise SystemExit(f"board_kernels: pycc left {[p.name for p in Path(tmp).iterdir()]}")
        # the table first: a table beside another build's module would call its exports with
        # the wrong types; without a table the package runs on the JIT until this finishes
        (out / (jit.MODULE + ".json")).unlink(missing_ok=True)
        for old in out.glob(jit.MODULE + ".*"):
            old.unlink()
        target = out / built[0].name
        shutil.move(built[0], target)
    tab = out / (jit.MODULE + ".json.tmp")
    tab.write_text(json.dumps({"exports": table}) + "\n")
    tab.replace(out / (jit.MODULE + ".json"))
    print(f"board_kernels: {n} exports of {len(table)} kernels compiled in "
          f"{time.perf_counter() - t0:.0f} s -> {target} ({target.stat().st_size / 1e6:.1f} MB)",
          file=sys.stderr)


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    rest = []
    if "--" in argv:
        i = argv.index("--")
        argv, rest = argv[:i], argv[i + 1:]
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    r = sub.add_parser("record", help="run a skyfix command (after --) and record its kernels' types")
    r.add_argument("types", type=Path)
    b = sub.add_parser("build", help="compile the recorded kernels ahead of time")
    b.add_argument("--types", type=Path, default=None,
                   help="the record (default: the one the installed package ships)")
    b.add_argument("--out", type=Path, default=None, help="folder (default: the installed package)")
    b.add_argument("--cpu", default="host",
                   help="LLVM CPU name to compile for (default: this machine's; 'generic' for any "
                        "x86-64): name the rover's processor when the image is built elsewhere")
    args = ap.parse_args(argv)
    if args.what == "record":
        if not rest:
            raise SystemExit("record: give the skyfix command after --")
        record(args.types, rest)
    else:
        types_path = args.types
        if types_path is None:
            import skyfix

            types_path = Path(skyfix.__file__).resolve().parent / "board_kernels.json"
        if not types_path.is_file():
            raise SystemExit(f"board_kernels: no record of kernel types at {types_path}")
        build(types_path, args.out, args.cpu)


if __name__ == "__main__":
    main()
