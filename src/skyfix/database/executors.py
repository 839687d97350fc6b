"""Where the build's blocks run: in this process (tests, one worker), an embedded Dask
``LocalCluster`` (the default), or an existing Dask cluster by address; and their option checks.
"""

from __future__ import annotations

import logging
import os
from concurrent.futures import Executor, Future
from contextlib import contextmanager

from ..errors import ParameterError
from ..optional import require


log = logging.getLogger(__package__)  # messages name the stage, as before the split


class InProcessExecutor(Executor):
    """Runs each task at once in the calling process (``--workers 0``); numba uses all its threads."""

    def submit(self, fn, /, *args, **kwargs):
        f = Future()
        try:
            f.set_result(fn(*args, **kwargs))
        except Exception as e:  # delivered through the future, like any executor
            f.set_exception(e)
        return f


def is_whole_at_least_0(v) -> bool:
    """A count given by a user: a whole number >= 0 (3.0 counts, True and "3" do not)."""
    try:
        return not isinstance(v, bool) and int(v) == v and v >= 0
    except (TypeError, ValueError, OverflowError):
        return False


def check_executor_options(workers: int | None, scheduler: str | None) -> None:
    """Refuse bad ``workers`` / ``scheduler`` values (before a build touches any file)."""
    if workers is not None and scheduler is not None:
        raise ParameterError("give either --workers or --scheduler, not both")
    if workers is not None:
        if not is_whole_at_least_0(workers):
            raise ParameterError(f"--workers must be a whole number >= 0 (0: in this process), got {workers}")
    if scheduler is not None:
        why = "not a string"
        if isinstance(scheduler, str):
            require("distributed", "--scheduler (an existing Dask cluster)")
            from distributed.comm import get_address_host_port

            # Parsed here, not left to Client(): a Client that fails on a malformed address (an
            # unknown scheme) hangs for 40 s at exit closing itself, and prints a traceback.
            try:
                get_address_host_port(scheduler)
                return
            except ValueError as e:  # "missing port number", "unknown address scheme"
                why = str(e)
        raise ParameterError(f"--scheduler {scheduler!r} is not a Dask scheduler address ({why}): give "
                             "tcp://HOST:PORT")
    elif workers != 0:
        require("distributed", "building with worker processes (--workers N, the default)",
                "--workers 0 to build in this process")


def default_workers() -> int:
    """Worker processes for a build by default: the cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


PRE_SPAWN = "distributed.nanny.pre-spawn-environ"

#: glibc malloc settings for the embedded cluster's workers [bytes]. Dask's own
#: (MALLOC_TRIM_THRESHOLD_ 64 KiB, to hand freed memory back at once) also fixes glibc's mmap
#: threshold at 128 KiB, so every render buffer larger than that is a fresh mapping whose pages
#: fault in anew: 2.1 M minor faults for a 2 x 2 km build, 11 % of its CPU in the kernel. Kept
#: on the heap up to 16 MiB (the render buffers of a block) and trimmed beyond 64 MiB free, the
#: faults fall tenfold (benchmarks/bench_build_db.py --malloc-ab).
WORKER_MALLOC = {"MALLOC_MMAP_THRESHOLD_": str(16 << 20), "MALLOC_TRIM_THRESHOLD_": str(64 << 20)}


def worker_environ() -> dict:
    """The environment the embedded cluster's workers start with: Dask's, malloc settings ours."""
    import dask

    return {**(dask.config.get(PRE_SPAWN, default=None) or {}), **WORKER_MALLOC}


@contextmanager
def make_executor(workers: int | None = None, scheduler: str | None = None):
    """Yield ``(executor, slots, single_thread)`` for a build.

    workers : 0 = in the calling process; N = an embedded Dask LocalCluster of N single-threaded
        worker processes (default: one per core)
    scheduler : address of an existing Dask scheduler (``tcp://HOST:PORT``); its workers must see
        the DEM and the output at the same paths and import skyfix
    """
    check_executor_options(workers, scheduler)
    if scheduler is None and workers == 0:
        yield InProcessExecutor(), 1, False
        return
    import dask
    from dask.distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, ValueError) as e:  # refused, unknown host, timed out
            raise ParameterError(f"cannot reach the Dask scheduler at {scheduler}: {e} (is it running, "
                                 "and is the address tcp://HOST:PORT right?)") from None
        with client:
            slots = max(1, sum(client.nthreads().values()))
            yield client.get_executor(pure=False), slots, True
        return
    n = default_workers() if workers is None else int(workers)
    dlog = logging.getLogger("distributed")
    if not log.isEnabledFor(logging.INFO):  # the cluster's start/stop chatter only with -v
        dlog.setLevel(logging.ERROR)
    # The worker processes start with Ctrl-C ignored (a child inherits SIG_IGN, and Python then
    # installs no KeyboardInterrupt handler): an interrupt reaches this process alone, which
    # closes the cluster, instead of every worker printing its traceback.
    # Dask sets its workers' malloc settings (MALLOC_TRIM_THRESHOLD_) in this process's own
    # environment, where every later child would inherit them: put the environment back after.
    environ = dict(os.environ)
    try:
        # The scheduler serves HTTP even without a dashboard (dashboard_address=None still took
        # port 8787, and a second build on the host warned in four lines): a free local port.
        with _sigint_ignored(), dask.config.set({PRE_SPAWN: worker_environ()}):
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                   dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR)
        with cluster, Client(cluster) as client:
            yield client.get_executor(pure=False), n, True
    finally:
        for k in set(os.environ) - set(environ):
            del os.environ[k]
        os.environ.update(environ)


@contextmanager
def _sigint_ignored():
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)
