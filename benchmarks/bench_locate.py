"""Full-database search: wall time and peak RSS of the locate process (targets <= 10 s, 256 MB).

On the real store (default ``/work/data/sierra_7km_5m.zarr``, 1401 x 1401 positions x 360 bins):

1. a body-frame query profile is rendered from the store's DEM at a known off-grid position
   (``skyfix.pose.synthetic_profile``: heading, noise, view width, tilt as given), or read from
   ``--profile P.json`` (then ``--truth-x/--truth-y`` tell where it was taken, if known);
2. ``skyfix locate --profile P --db DB`` runs ``--repeat`` times under ``/usr/bin/time -v``
   (database level only: no ``--dem`` refinement): wall time and peak RSS of the whole process,
   imports included, and whether the fix is the grid position nearest the truth;
3. the matcher alone (``match_database``) runs as many times in its own process for the breakdown:
   waiting for blocks (read/decompress not hidden by the reader thread), coarse pass, exact pass,
   and CPU time of the scoring thread and of the reader thread.

Medians are printed with the machine's load (``os.getloadavg``): timings on a shared 2-core
machine are noisy; CPU seconds are steadier than wall seconds there.

    PYTHONPATH=src python benchmarks/bench_locate.py [--db DB] [--repeat 3] [--preset fast]
        [--heading 123] [--noise 0.2] [--coverage 360] [--pitch 0 --roll 0] [--profile P.json]
        [--load [N]] [--ab-index] [--board-python DIR/bin/python]

With ``--load``, the locate runs are repeated while N processes (one per core by default) spin,
started and stopped by the benchmark itself: the search must stay within 2x of its idle time.
With ``--ab-index`` every run is repeated on a twin of the store without its coarse index
(hard-linked, removed afterwards), the two alternated, and the ratios printed. With
``--board-python`` the runs use a board install's Python and its own skyfix (the kernels compiled
ahead of time, numba never imported), as on the rover; this script itself runs in the ground
install (it renders the query profile).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from installs import child_env

ROOT = Path(__file__).resolve().parents[1]

MATCH_CHILD = r"""
import json, re, sys, time
t_start = time.perf_counter()
from skyfix.database import open_database
from skyfix.formats import read_profile_json
from skyfix.match import PRESETS, match_database
db = open_database(sys.argv[1])
prof = read_profile_json(sys.argv[2])
t0 = time.perf_counter(); c0 = time.process_time()
res = match_database(db, prof.elevation_deg, PRESETS[sys.argv[3]])
c = res.candidates[0]
print(json.dumps({"search_s": time.perf_counter() - t0, "search_cpu_s": time.process_time() - c0,
                  "process_s": time.perf_counter() - t_start,
                  # VmHWM, not ru_maxrss: the latter keeps the parent's peak across fork and exec
                  "peak_rss_mb": int(re.search(r"VmHWM:\s+(\d+)",
                                               open("/proc/self/status").read()).group(1)) / 1024,
                  "positions": res.n_positions, "scored_exact": res.n_scored_exact,
                  "timing": res.timing, "row": c.row, "col": c.col, "heading_deg": c.heading_deg}))
"""


#: the interpreter of the measured runs (``--board-python``: another install's)
PYTHON = [sys.executable]


def _env():
    return child_env(PYTHON[0], own_src=str(ROOT / "src"))


def make_profile(db_path, out, x, y, args):
    from skyfix.database import open_database
    from skyfix.dem import load_dem
    from skyfix.formats import write_profile_json
    from skyfix.pose import synthetic_profile

    db = open_database(db_path)
    dem = load_dem(db.attrs["dem"]["source"])
    prof = synthetic_profile(dem, x, y, args.heading, args.pitch, args.roll,
                             camera_height_m=db.camera_height_m, n_bins=db.azimuth_bins,
                             noise_deg=args.noise, coverage_deg=args.coverage, rng=args.seed)
    write_profile_json(out, prof)


def run_locate(db, profile, preset, fix_path):
    cmd = ["/usr/bin/time", "-v", PYTHON[0], "-m", "skyfix.cli.main", "locate", "--profile",
           str(profile), "--db", str(db), "--preset", preset, "-o", str(fix_path), "--overwrite"]
    out = subprocess.run(cmd, capture_output=True, text=True, env=_env())
    if out.returncode:
        raise SystemExit(f"locate failed ({out.returncode}):\n{out.stderr[-3000:]}")
    m = re.search(r"Elapsed \(wall clock\) time.*: (?:(\d+):)?(\d+):([\d.]+)", out.stderr)
    wall = int(m.group(1) or 0) * 3600 + int(m.group(2)) * 60 + float(m.group(3))
    rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", out.stderr).group(1)) / 1024
    cpu = sum(float(v) for v in re.findall(r"(?:User|System) time \(seconds\): ([\d.]+)", out.stderr))
    return wall, rss, cpu, json.loads(Path(fix_path).read_text())


def run_match(db, profile, preset):
    out = subprocess.run([PYTHON[0], "-c", MATCH_CHILD, str(db), str(profile), preset],
                         capture_output=True, text=True, env=_env())
    if out.returncode:
        raise SystemExit(f"matcher failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--db", default="/work/data/sierra_7km_5m.zarr")
    ap.add_argument("--profile", help="body-frame profile JSON (default: rendered at --truth-x/y)")
    ap.add_argument("--truth-x", type=float, help="[m] (default: near the centre, off-grid)")
    ap.add_argument("--truth-y", type=float)
    ap.add_argument("--heading", type=float, default=123.0, help="[deg]")
    ap.add_argument("--pitch", type=float, default=0.0, help="[deg]")
    ap.add_argument("--roll", type=float, default=0.0, help="[deg]")
    ap.add_argument("--noise", type=float, default=0.2, help="[deg] per bin")
    ap.add_argument("--coverage", type=float, default=360.0, help="[deg] view width")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--load", type=int, nargs="?", const=os.cpu_count(), default=0,
                    help="then rerun the locate runs with this many busy-looping processes started "
                         "and stopped by the benchmark (default with the flag: one per core), and "
                         "print the loaded / idle wall-time ratio")
    ap.add_argument("--ab-index", action="store_true",
                    help="also run every measurement on a twin of the store without its coarse "
                         "index (hard links, removed afterwards), alternated run by run, and print "
                         "the ratios")
    ap.add_argument("--board-python", default=sys.executable,
                    help="run skyfix (locate and the matcher) with this Python: a board install "
                         "(scripts/board_install.sh DIR [--no-jit]), as a rover carries it")
    args = ap.parse_args()
    PYTHON[0] = args.board_python

    from skyfix.database import open_database

    db = open_database(args.db)  # refuses an incomplete store
    ny, nx = db.shape
    if (args.truth_x is None) != (args.truth_y is None):
        ap.error("give --truth-x and --truth-y together")
    if args.truth_x is not None:
        tx, ty = args.truth_x, args.truth_y
    elif args.profile:  # a profile of its own: no truth to score against unless given
        tx = ty = None
    else:
        tx, ty = db.xy_of(ny // 2 + 37, nx // 3)
        tx, ty = float(tx) + 1.7, float(ty) - 2.2  # off-grid
    tr, tc = (int(v) for v in db.index_of(tx, ty)) if tx is not None else (None, None)
    print(f"store {args.db}: {nx} x {ny} = {nx * ny:,} positions x {db.azimuth_bins} bins, "
          f"{db.n_blocks} blocks; preset {args.preset}; skyfix run by {PYTHON[0]}")
    stores = {"with index": args.db}
    twin = None
    if args.ab_index:
        if not db.has_coarse_index:
            raise SystemExit(f"{args.db} has no coarse index to compare against: run its build-db "
                             "command again to add it")
        twin = Path(args.db).parent / f".{Path(args.db).name}.noindex-{os.getpid()}"
        hardlink_without_index(Path(args.db), twin)
        stores["without"] = str(twin)
    try:
        with tempfile.TemporaryDirectory() as d:
            prof = Path(args.profile) if args.profile else Path(d) / "query.json"
            if not args.profile:
                make_profile(args.db, prof, tx, ty, args)
                print(f"query rendered at ({tx:.1f}, {ty:.1f}) [nearest grid row {tr}, col {tc}], "
                      f"heading {args.heading}, pitch {args.pitch}, roll {args.roll}, noise "
                      f"{args.noise} deg, view {args.coverage} deg")
            runs = {k: {"loc": [], "mat": [], "loaded": []} for k in stores}
            loads = []
            for _ in range(args.repeat):  # the stores alternated, run by run
                loads.append(os.getloadavg()[0])
                for k, path in stores.items():
                    runs[k]["loc"].append(run_locate(path, prof, args.preset, Path(d) / "fix.json"))
                for k, path in stores.items():
                    runs[k]["mat"].append(run_match(path, prof, args.preset))
            load_during = None
            if args.load:
                busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
                        for _ in range(args.load)]
                try:
                    time.sleep(3.0)  # let the scheduler see them
                    for _ in range(args.repeat):
                        for k, path in stores.items():
                            runs[k]["loaded"].append(run_locate(path, prof, args.preset,
                                                                Path(d) / "fix.json"))
                    load_during = os.getloadavg()[0]
                finally:
                    for b in busy:
                        b.kill()
                        b.wait()
    finally:
        if twin is not None:
            shutil.rmtree(twin, ignore_errors=True)
    print(f"load average (1 min) during the runs: {', '.join(f'{v:.1f}' for v in loads)} on "
          f"{os.cpu_count()} cores")
    for k, r in runs.items():
        if len(runs) > 1:
            print(f"--- the store {k} its coarse index")
        report(db, r, args, tx, ty, tr, tc, load_during)
    if len(runs) > 1:
        med = statistics.median
        a, b = runs["with index"], runs["without"]
        def ratio(f, key):
            return med(f(v) for v in a[key]) / med(f(v) for v in b[key])

        print(f"with / without the index: locate wall {ratio(lambda v: v[0], 'loc'):.2f}, CPU "
              f"{ratio(lambda v: v[2], 'loc'):.2f}; matcher wall "
              f"{ratio(lambda m: m['search_s'], 'mat'):.2f}, CPU "
              f"{ratio(lambda m: m['search_cpu_s'], 'mat'):.2f}"
              + (f"; loaded locate wall {ratio(lambda v: v[0], 'loaded'):.2f}" if a["loaded"] else ""))


def hardlink_without_index(src: Path, dst: Path) -> None:
    """A twin of the store at ``dst`` without its coarse index: every file hard-linked (no copy,
    no extra disk), the ``coarse`` folder left out."""
    for root, dirs, files in os.walk(src):
        rel = Path(root).relative_to(src)
        if rel.parts[:1] == ("coarse",):
            continue
        (dst / rel).mkdir(parents=True, exist_ok=True)
        for f in files:
            os.link(Path(root) / f, dst / rel / f)


def report(db, r, args, tx, ty, tr, tc, load_during) -> None:
    med = statistics.median
    loc, mat, loaded = r["loc"], r["mat"], r["loaded"]
    walls = [w for w, _, _, _ in loc]
    print(f"skyfix locate (whole process, {args.repeat} runs): wall median {med(walls):.2f} s "
          f"(runs {', '.join(f'{w:.2f}' for w in walls)}), CPU median "
          f"{med(c for _, _, c, _ in loc):.2f} s, peak RSS max {max(r for _, r, _, _ in loc):.0f} MB")
    if loaded:
        lw = [w for w, _, _, _ in loaded]
        print(f"with {args.load} busy-looping processes (load {load_during:.1f}): wall median "
              f"{med(lw):.2f} s (runs {', '.join(f'{w:.2f}' for w in lw)}), CPU median "
              f"{med(c for _, _, c, _ in loaded):.2f} s; loaded / idle wall {med(lw) / med(walls):.2f} "
              "(target <= 2)")
    fix = loc[-1][3]
    if tr is not None:
        fr, fc = (int(v) for v in db.index_of(fix["x"], fix["y"]))
        err = ((fix["x"] - tx) ** 2 + (fix["y"] - ty) ** 2) ** 0.5
        print(f"  fix ({fix['x']:.1f}, {fix['y']:.1f}) grid heading {fix['grid_heading_deg']:.2f}: "
              f"{err:.1f} m from the truth; nearest grid position to the truth: {(fr, fc) == (tr, tc)}")
    t = {k: med(m["timing"][k] for m in mat) for k in mat[0]["timing"]}
    print(f"matcher alone (medians of {args.repeat}): search wall {med(m['search_s'] for m in mat):.2f} s, "
          f"CPU {med(m['search_cpu_s'] for m in mat):.2f} s; process "
          f"{med(m['process_s'] for m in mat):.2f} s, peak RSS {max(m['peak_rss_mb'] for m in mat):.0f} MB")
    print(f"  waiting for blocks (read/decompress not overlapped) {t['read_s']:.2f} s "
          f"[reader thread CPU {t['reader_cpu_s']:.2f} s], coarse pass {t['coarse_s']:.2f} s, "
          f"exact pass {t['exact_s']:.2f} s on {mat[0]['scored_exact']:,} of "
          f"{mat[0]['positions']:,} positions, nms {t['nms_s']:.2f} s; scoring thread CPU "
          f"{t['main_cpu_s']:.2f} s; blocks decoded {t.get('blocks_read', db.n_blocks):.0f} of "
          f"{db.n_blocks}")
    m = mat[-1]
    if tr is not None:
        print(f"  top candidate is the truth's grid position: {(m['row'], m['col']) == (tr, tc)} "
              f"(row {m['row']}, col {m['col']}; heading {m['heading_deg']:.2f}, truth {args.heading})")

if __name__ == "__main__":
    main()
