"""The board segment as a rover runs it: images to fix, one core, 256 MB for everything.

For each case (simulated acquisitions inside the database's area: a full turn, a 10 deg tilted
rover, a position where near terrain hides half the turn), runs ``skyfix locate ACQ --db DB --dem
DEM`` and then ``skyfix heading`` (position 15 m off, prior 5 deg off) as whole processes, pinned
to one core (``taskset``), once free and once inside a memory cgroup limited to ``--limit-mb``
(no swap: cgroup v1 ``memsw`` or v2 ``swap.max``, where the machine allows it; otherwise it says
the limit was not enforced). Prints per run: wall and CPU seconds, peak RSS (the process's own
high-water mark) and peak anonymous memory (sampled from /proc every 20 ms), killed or not,
position and heading error, confidence; the limited/free time ratio over the pairs of runs that
both succeeded (the others are listed); and the load average.

    python benchmarks/bench_board.py --db DB --dem DEM [--cases 3] [--limit-mb 256] [--cpu 0]
        [--work DIR] [--board-python PATH] [--detectors dp,fuse]

``--board-python`` runs the board commands with another environment's Python: a board install
(``pip install skyfix``, no extras), as a rover carries it. The acquisitions are simulated here,
which needs the ground install this script runs in. Measured in the ground install, the board
commands carry what its extras drag in (numba loads SciPy's BLAS where SciPy is installed).
``--detectors dp,fuse`` runs every command with each detector in turn, side by side in one run
(the time and memory the learned network adds on the board, on the same acquisitions).

The requirement's database is the README's 7 x 7 km at 5 m over the Sierra DEM:
``skyfix build-db ../shared/data/dem/sierra_nevada_30m.tif -o DB --bounds 297800 4143100
304800 4150100 --spacing-m 5`` (the DEM's work CRS, UTM 11N; a store built before 2026-11-28,
in its USA Albers, is refused: rebuild it).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from installs import child_env


def _cgroup(limit_mb: int):
    """(path of a fresh memory cgroup limited to ``limit_mb`` without swap, how) or (None, why)."""
    v1 = Path("/sys/fs/cgroup/memory")
    v2 = Path("/sys/fs/cgroup/unified") if Path("/sys/fs/cgroup/unified/cgroup.procs").exists() \
        else Path("/sys/fs/cgroup")
    name = f"skyfix_board_{os.getpid()}"
    limit = str(limit_mb * 1024 * 1024)
    try:
        if (v1 / "memory.limit_in_bytes").exists():
            g = v1 / name
            g.mkdir(exist_ok=True)
            (g / "memory.limit_in_bytes").write_text(limit)
            sw = g / "memory.memsw.limit_in_bytes"
            if sw.exists():
                sw.write_text(limit)
                return g, "cgroup v1 memory, no swap (memsw)"
            (g / "memory.swappiness").write_text("0")
            return g, "cgroup v1 memory, swappiness 0 (no memsw accounting)"
        if (v2 / "cgroup.controllers").exists() and "memory" in (v2 / "cgroup.controllers").read_text():
            g = v2 / name
            g.mkdir(exist_ok=True)
            (g / "memory.max").write_text(limit)
            if (g / "memory.swap.max").exists():
                (g / "memory.swap.max").write_text("0")
                return g, "cgroup v2 memory.max, swap.max 0"
            return g, "cgroup v2 memory.max, swap not limited (no swap accounting)"
    except OSError as e:
        return None, f"not enforced: cannot create a memory cgroup ({e.strerror})"
    return None, "not enforced: no memory cgroup controller on this machine"


#: runs ``python -m skyfix.cli.main ARGS`` and, as it exits, writes its own peak RSS (VmHWM,
#: kB) to the file $SKYFIX_BENCH_HWM: sampling /proc misses a short peak, and getrusage's
#: ru_maxrss carries the parent's (this benchmark's) peak across fork and exec
HWM_RUNNER = ("import atexit, os, re, runpy, sys\n"
              "def _hwm():\n"
              "    m = re.search(r'VmHWM:\\s+(\\d+)', open('/proc/self/status').read())\n"
              "    open(os.environ['SKYFIX_BENCH_HWM'], 'w').write(m.group(1))\n"
              "atexit.register(_hwm)\n"
              "sys.argv[0] = 'skyfix'\n"
              "runpy.run_module('skyfix.cli.main', run_name='__main__', alter_sys=True)\n")


def _run(cmd, cgroup=None, cpu=0, env=None):
    """Run ``cmd`` (``[python, -m, skyfix.cli.main, ...]``) pinned to ``cpu`` (and inside
    ``cgroup``). Peak RSS is the process's own high-water mark, written as it exits (sampled
    from /proc every 20 ms where it was killed first); peak anonymous memory is sampled (the
    kernel keeps no high-water mark of it). Returns a dict."""
    import tempfile

    def enter():
        if cgroup is not None:
            (cgroup / "cgroup.procs").write_text(str(os.getpid()))
        os.sched_setaffinity(0, {cpu})

    assert cmd[1:3] == ["-m", "skyfix.cli.main"], cmd
    with tempfile.TemporaryDirectory() as tmp:
        hwm_file = Path(tmp) / "hwm"
        env = dict(os.environ if env is None else env, SKYFIX_BENCH_HWM=str(hwm_file))
        # outputs to files, not pipes: a child that writes more than a pipe holds (a long
        # traceback) would block until read, and they are read only once it exits
        with open(Path(tmp) / "out", "w+") as fo, open(Path(tmp) / "err", "w+") as fe:
            t0 = time.perf_counter()
            p = subprocess.Popen([cmd[0], "-c", HWM_RUNNER, *cmd[3:]], stdout=fo, stderr=fe,
                                 text=True, preexec_fn=enter, env=env)
            rss = anon = 0
            status = Path(f"/proc/{p.pid}/status")
            while p.poll() is None:
                try:
                    for line in status.read_text().splitlines():
                        if line.startswith("VmRSS:"):
                            rss = max(rss, int(line.split()[1]))
                        elif line.startswith("RssAnon:"):
                            anon = max(anon, int(line.split()[1]))
                except OSError:
                    pass
                time.sleep(0.02)
            wall = time.perf_counter() - t0
            fo.seek(0)
            fe.seek(0)
            out, err = fo.read(), fe.read()
        if hwm_file.is_file() and hwm_file.read_text().strip():
            rss = max(rss, int(hwm_file.read_text()))
    return {"rc": p.returncode, "wall_s": wall, "peak_rss_mb": rss / 1024, "peak_anon_mb": anon / 1024,
            "killed": p.returncode in (-9, 137), "stdout": out, "stderr": err}


def _children_cpu():
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _cases(dem, db, n, work: Path, seed=0):
    """Acquisitions inside the database's grid: full turns (one tilted 10 deg) and one where near
    terrain hides half the turn. Returns [(name, folder, truth)]."""
    from skyfix.formats import Truth
    from skyfix.horizon import render_horizons
    from skyfix.simulate import simulate_acquisition

    rng = np.random.default_rng(seed)
    xs, ys = np.asarray(db.x_coords), np.asarray(db.y_coords)
    m = 4 * db.spacing_m
    lo_x, hi_x, lo_y, hi_y = xs.min() + m, xs.max() - m, ys.min() + m, ys.max() - m
    pool = rng.uniform([lo_x, lo_y], [hi_x, hi_y], (400, 2))
    hb = render_horizons(dem, pool[:, 0], pool[:, 1], azimuth_bins=72)
    near = np.nanmean(hb.skyline_distance_m < 60.0, axis=1)
    hidden = pool[int(np.argmax(near))]
    plans = [("full turn", pool[0], 0.0), ("tilted 10 deg", pool[1], 10.0),
             (f"near terrain hides {100 * near.max():.0f} %", hidden, 0.0)]
    for k in range(3, n):
        plans.append((f"full turn {k}", pool[k], 0.0))
    out = []
    for name, (x, y), pitch in plans[:n]:
        truth = Truth(float(x), float(y), float(rng.uniform(0, 360)), pitch, 0.0)
        seed = int(rng.integers(1 << 30))  # drawn either way: the next case's truth must not move
        folder = work / name.replace(" ", "_").replace("%", "pct")
        acq = folder / "acquisition.json"
        if acq.exists():  # a rerun: the truth it was rendered with, whatever drew it
            t = json.loads(acq.read_text())["truth"]
            truth = Truth(t["x"], t["y"], t["yaw_deg"], t["pitch_deg"], t["roll_deg"])
        else:
            simulate_acquisition(dem, truth, folder, camera="navcam", tilt_deg=15.0, overwrite=True,
                                 seed=seed, attitude_prior=(0.0, 0.0))
        out.append((name, folder, truth))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--db", required=True)
    ap.add_argument("--dem", required=True)
    ap.add_argument("--cases", type=int, default=3)
    ap.add_argument("--limit-mb", type=int, default=256)
    ap.add_argument("--cpu", type=int, default=0)
    ap.add_argument("--work", default="/tmp/skyfix_bench_board")
    ap.add_argument("--board-python", default=sys.executable,
                    help="the Python of the install that runs the board commands")
    ap.add_argument("--detectors", default="dp",
                    help="comma-separated detection methods, each run in turn (e.g. dp,fuse)")
    args = ap.parse_args(argv)
    if args.cases < 1:
        ap.error(f"--cases must be >= 1, got {args.cases}")
    detectors = [d.strip() for d in args.detectors.split(",") if d.strip()]
    unknown = sorted(set(detectors) - {"dp", "bayes", "net", "fuse"})
    if unknown or not detectors:
        ap.error(f"--detectors: unknown {', '.join(unknown) or '(none given)'}; choose among dp, "
                 "bayes, net, fuse")
    from skyfix.database import open_database
    from skyfix.dem import load_dem
    from skyfix.north import meridian_convergence_deg, true_heading_deg

    dem, db = load_dem(args.dem), open_database(args.db)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    cases = _cases(dem, db, args.cases, work)
    cg, how = _cgroup(args.limit_mb)
    print(f"memory limit {args.limit_mb} MB: {how}; pinned to CPU {args.cpu}; load average "
          f"{' '.join(f'{v:.2f}' for v in os.getloadavg())}", flush=True)
    skyfix = [args.board_python, "-m", "skyfix.cli.main", "-q"]
    env = child_env(args.board_python)
    aot = subprocess.run([args.board_python, "-c", "from skyfix import jit; print(jit.ahead_of_time())"],
                         capture_output=True, text=True, env=env).stdout.strip() == "True"
    print(f"board commands run by {args.board_python}; kernels "
          f"{'compiled ahead of time (numba not loaded)' if aot else 'by numba JIT (cached)'}",
          flush=True)
    print(f"{'case':30s} {'command':8s} {'detect':6s} {'limit':6s} {'wall s':>7s} {'cpu s':>6s} {'RSS MB':>7s} "
          f"{'anon MB':>7s} {'killed':>6s} {'pos m':>7s} {'head deg':>8s} {'conf':>5s}")
    ratios = []
    failures = []  # (case, command, detector) whose free or limited run did not succeed
    cpu_by = {d: {} for d in detectors}  # detector -> (case, command) -> free run's CPU [s]
    try:
        for name, folder, truth in cases:
            conv = meridian_convergence_deg(dem.crs_wkt, truth.x, truth.y)
            true_h = true_heading_deg(truth.yaw_deg, conv)
            off = 15.0
            hx, hy = truth.x + off * math.sin(1.0), truth.y + off * math.cos(1.0)
            cmds = {
                "locate": [*skyfix, "locate", str(folder), "--db", args.db, "--dem", args.dem, "-o",
                           str(work / "fix.json"), "--overwrite"],
                "heading": [*skyfix, "heading", str(folder), "--dem", args.dem, "--x", f"{hx:.2f}",
                            "--y", f"{hy:.2f}", "--heading-prior-deg", f"{(true_h + 5) % 360:.2f}",
                            "-o", str(work / "heading.json"), "--overwrite"],
            }
            for (cname, cmd), det in ((c, d) for c in cmds.items() for d in detectors):
                cmd = [*cmd, "--detector", det]
                walls, failed = {}, False
                for lim in ("free", "limit"):
                    if lim == "limit" and cg is None:
                        continue
                    c0 = _children_cpu()
                    r = _run(cmd, cg if lim == "limit" else None, args.cpu, env)
                    cpu = _children_cpu() - c0
                    walls[lim] = r["wall_s"]
                    failed |= r["rc"] != 0
                    if lim == "free" and r["rc"] == 0:
                        cpu_by[det][(name, cname)] = cpu
                    pos = head = conf = float("nan")
                    if r["rc"] == 0:
                        res = json.loads((work / ("fix.json" if cname == "locate" else "heading.json")).read_text())
                        pos = math.hypot(res["x"] - truth.x, res["y"] - truth.y) if cname == "locate" else float("nan")
                        head = abs((res["grid_heading_deg"] - truth.yaw_deg + 180) % 360 - 180)
                        conf = res["confidence"]
                    elif not r["killed"]:
                        print(f"   {cname} failed: {r['stderr'].strip()[-300:]}")
                    print(f"{name[:30]:30s} {cname:8s} {det:6s} {lim:6s} {r['wall_s']:7.1f} {cpu:6.1f} "
                          f"{r['peak_rss_mb']:7.0f} {r['peak_anon_mb']:7.0f} {str(r['killed']):>6s} "
                          f"{pos:7.2f} {head:8.3f} {conf:5.2f}", flush=True)
                if failed:
                    failures.append(f"{name} {cname} {det}")
                elif "limit" in walls:  # a run killed early or failing fast is not "fast"
                    ratios.append(walls["limit"] / walls["free"])
    finally:
        if cg is not None:
            try:
                cg.rmdir()
            except OSError:
                pass
    if ratios:
        print(f"limited / free wall time: median {np.median(ratios):.2f}, worst {max(ratios):.2f} "
              f"(target <= 1.25; the {len(ratios)} pairs where both runs succeeded)")
    if failures:
        print(f"FAILED or killed, left out of the ratios: {'; '.join(failures)}")
    for det in detectors[1:]:
        for cname in ("locate", "heading"):
            pairs = [(cpu_by[det][k], cpu_by[detectors[0]][k]) for k in cpu_by[det]
                     if k[1] == cname and k in cpu_by[detectors[0]]]
            if pairs:
                print(f"{cname} CPU, {det} / {detectors[0]} (free runs): " + ", ".join(
                    f"{a / b:.2f}" for a, b in pairs) + f" (median {np.median([a / b for a, b in pairs]):.2f})")
    print(f"load average after: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    shutil.rmtree(work / "tmp", ignore_errors=True)


if __name__ == "__main__":
    main()
