"""The board commands' numba kernels, or their ahead-of-time build where an install made one.

Every kernel of the board path (detection, the database reader, the search, the horizon renderer)
is declared with :func:`njit`. Normally that is ``numba.njit``: compiled on first use, cached on
disk. A board install (``scripts/board_install.sh``) also compiles them ahead of time, with numba's
``pycc``, into one extension module beside the package (``skyfix/_board_kernels*.so``, the
argument types of each export in ``skyfix/_board_kernels.json``). Where that module exists a
kernel runs from it and numba is not imported at all: numba and LLVM are 124 MB of a board
process's resident memory once the first cached kernel loads, and starting LLVM's code
generator costs 0.23 s of every run (docs/board-memory.md).

The ahead-of-time build covers the argument types recorded by ``scripts/board_kernels.py
record`` (the board commands on the benchmark's acquisitions; ``skyfix/board_kernels.json``).
A call with other types (a dtype, an array layout, a writeable flag the record never saw) is
compiled by numba's JIT as everywhere else, so the answer never depends on the build: the
exported machine code is the same compilation of the same source. pycc's exports check nothing
(an int64 array passed for a float64 one is read as float64), so the types are checked here,
before each call, the way numba's own dispatcher would type the arguments.

The ahead-of-time kernels run on one thread (pycc does not build numba's parallel loops), as the
rover's single core does. ``SKYFIX_JIT=1`` ignores the build; ``SKYFIX_BOARD_KERNELS=DIR`` loads
it from DIR instead of the package (tests build one there).
"""

from __future__ import annotations

import functools
import importlib.util
import json
import logging
import os
import types
from pathlib import Path

import numpy as np

#: the extension module's name; its signature table is ``MODULE + ".json"`` beside it
MODULE = "_board_kernels"
#: a kernel's export name(s): its module and qualified name, dots as "__", then "__<k>" per signature
_SEP = "__"

_state: dict = {}  # "aot": (module, table) or None, decided once
_registry: list = []  # JIT mode: every dispatcher made by njit, for the signature record


def export_name(func) -> str:
    """The name a kernel's ahead-of-time exports carry (``module__qualname``)."""
    return (func.__module__ + "." + func.__qualname__).replace(".", _SEP)


def _load_aot():
    """(extension module, {export: [arg specs]}) or None."""
    if "aot" in _state:
        return _state["aot"]
    _state["aot"] = None
    if os.environ.get("SKYFIX_JIT", "") not in ("", "0"):
        return None
    folder = os.environ.get("SKYFIX_BOARD_KERNELS") or str(Path(__file__).resolve().parent)
    table_path = Path(folder) / (MODULE + ".json")
    if not table_path.is_file():
        return None
    so = [p for p in Path(folder).glob(MODULE + ".*") if p.suffix in (".so", ".pyd")]
    if not so:
        return None
    try:
        spec = importlib.util.spec_from_file_location(f"skyfix.{MODULE}", so[0])
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        table = json.loads(table_path.read_text())
        exports = table["exports"]
    except (ImportError, OSError, ValueError, KeyError, TypeError) as e:
        # a build for another Python or machine, or a damaged table: the JIT gives the same
        # answers, at the cost the build was made to save; say so rather than fail every command
        logging.getLogger("skyfix.jit").warning(
            "the ahead-of-time kernels in %s cannot be used (%s: %s); compiling with numba instead "
            "(rebuild them: scripts/board_kernels.py build)", folder, type(e).__name__, e)
        return None
    _state["aot"] = (module, exports)
    return _state["aot"]


def ahead_of_time() -> bool:
    """True when kernels run from an ahead-of-time build (numba not loaded for them)."""
    return _load_aot() is not None


def num_threads() -> int:
    """numba's thread count, or 1 where the kernels run ahead of time (one thread): the serial
    kernels are the ones built, even after a fallback has loaded numba."""
    if _load_aot() is not None:
        return 1
    import numba

    return numba.get_num_threads()


# --- argument checks: what numba's typeof would say, against an export's recorded types --------

def accepts(spec, value) -> bool:
    """Whether ``value`` has the type ``spec`` records (as scripts/board_kernels.py encodes numba
    types), so that an export compiled for it reads the value right; numba would take it too."""
    kind = spec[0]
    if kind == "array":
        _, dtype, ndim, layout, readonly = spec
        if type(value) is not np.ndarray or value.ndim != ndim or value.dtype.name != dtype:
            return False
        if not value.dtype.isnative or not value.flags.aligned:
            return False
        if not readonly and not value.flags.writeable:
            return False
        if layout == "C":
            return value.flags.c_contiguous
        if layout == "F":
            return value.flags.f_contiguous and not value.flags.c_contiguous
        return True
    if kind == "scalar":
        name = spec[1]
        if isinstance(value, bool):
            return name == "bool"
        if isinstance(value, int):
            return name == "int64" and -(1 << 63) <= value < (1 << 63)
        if isinstance(value, float):
            return name == "float64"
        return isinstance(value, np.generic) and value.dtype.name == name
    return False


def _describe(value) -> str:
    """A value's type in a few words, for the fallback's warning."""
    if isinstance(value, np.ndarray):
        layout = "C" if value.flags.c_contiguous else "F" if value.flags.f_contiguous else "strided"
        ro = "" if value.flags.writeable else ", read-only"
        return f"{value.dtype.name}[{value.ndim}d, {layout}{ro}]"
    return type(value).__name__


class Kernel:
    """A kernel with ahead-of-time exports: calls the export whose recorded argument types fit,
    else numba's JIT build of the same function (numba imported then, not before)."""

    def __init__(self, func, options, exports):
        self.py_func = func
        self.options = options
        self._exports = exports  # [(callable, [arg spec, ...])]
        self._jit = None
        functools.update_wrapper(self, func)

    def __call__(self, *args):
        for fn, specs in self._exports:
            if len(specs) == len(args) and all(accepts(s, a) for s, a in zip(specs, args)):
                return fn(*args)
        if self._jit is None:
            # said once per kernel: loading numba costs the memory the build was made to save
            logging.getLogger("skyfix.jit").warning(
                "%s.%s: argument types the ahead-of-time build does not cover; compiling it "
                "with numba (%s)", self.py_func.__module__, self.py_func.__qualname__,
                ", ".join(_describe(a) for a in args))
        return self.jit()(*args)

    def jit(self):
        """numba's dispatcher of this function; other kernels it calls are their dispatchers."""
        if self._jit is None:
            try:
                import numba
            except ImportError:
                raise RuntimeError(
                    f"skyfix: the kernel {self.py_func.__module__}.{self.py_func.__qualname__} was "
                    f"not compiled ahead of time for these argument types and numba is not "
                    f"installed to compile it: install numba, or record these types and rebuild "
                    f"the kernels (scripts/board_kernels.py)") from None
            glb = dict(self.py_func.__globals__)
            for k in self.py_func.__code__.co_names:  # the globals the kernel reads
                v = glb.get(k)
                if isinstance(v, Kernel) and v is not self:
                    glb[k] = v.jit()
                elif v is range and k == "prange":
                    glb[k] = numba.prange
            f = types.FunctionType(self.py_func.__code__, glb, self.py_func.__name__,
                                   self.py_func.__defaults__, self.py_func.__closure__)
            f.__qualname__ = self.py_func.__qualname__
            f.__module__ = self.py_func.__module__
            self._jit = numba.njit(**self.options)(f)
        return self._jit


def njit(**options):
    """``numba.njit(**options)``, or the function's ahead-of-time exports where they exist."""
    def wrap(func):
        aot = _load_aot()
        if aot is not None:
            module, table = aot
            name = export_name(func)
            exports = [(getattr(module, e), specs) for e, specs in table.get(name, [])
                       if hasattr(module, e)]
            return Kernel(func, options, exports)
        import numba

        disp = numba.njit(**options)(func)
        _registry.append(disp)
        return disp
    return wrap


def __getattr__(name):
    # ``from skyfix.jit import prange``: numba's prange where numba compiles the kernels, else range
    # (an ahead-of-time kernel's loops are serial; a JIT fallback swaps numba's back in, Kernel.jit)
    if name == "prange":
        if _load_aot() is not None:
            return range
        import numba

        return numba.prange
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def registered():
    """The dispatchers :func:`njit` made in this process (JIT mode), for the signature record."""
    return list(_registry)
