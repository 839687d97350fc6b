"""Skyline detection on the real dev set (and simulated sets when the simulator exists).

Prints per image and overall: mean absolute row error [px] over columns where truth and detection
both have a skyline, share within 3 px and 10 px, false-skyline and missed-skyline rates over
valid columns, and milliseconds per megapixel (wall time on this machine: noisy when shared);
per set, how the detected columns fare by confidence bin (share within 3 px, share false); then
each dev image resampled to 4 MP, timed against the target of 1 s per 4-MP image, and the peak
RSS of a process detecting one 4-MP image (``--board-python``: also with a board install's
interpreter, the footprint a rover has) against the 256 MB budget.

    PYTHONPATH=src python benchmarks/bench_detect.py [--methods dp,bayes] [--data DIR]
        [--only NAME,...] [--set KEY=VALUE ...] [--cv [--cv-sim SIMS]] [--sim DIR]
        [--degrade grey|jpeg:Q|blur:S|denoise|resample:F] [--board-python PATH]

``--cv`` adds cross-validated tables for ``dp`` and ``fuse`` (whichever ``--methods`` names): the
images are dealt into ``--cv-folds`` folds by site (a Mars mosaic by its sol, so near-duplicate
mosaics of one site never sit on both sides; an Earth photo by itself; the folds of
``scripts/train_sky_net.py``), the sky classifier is retrained (same recipe as
``scripts/train_sky_model.py``) on the labelled mosaics of the other folds and each image is
detected with the model of its own fold. The pooled line also gives the share of columns
claimed on images whose truth holds no skyline at all (the no-sky mosaics).
``fuse`` also runs, on each image, the member of the shipped network's ensemble that held that
image's fold out (the same folds: the network's members were trained by them).

``--cv-net DIR`` scores ``net`` cross-validated: DIR holds ``fold_K.onnx`` (+ ``.json``) from
``scripts/train_sky_net.py --folds N --fold K``; each image is detected by the fold model that
did not see it (its ``held_out`` list). The per-column confidence is calibrated held out too
(isotonic, fitted on the other folds' columns), ``min_confidence`` is chosen on the other folds
(least false + missed), and a reliability table of the calibrated confidence is printed.
``--write-calibration MODEL.json`` stores the calibration fitted on every fold's columns (and the
chosen ``min_confidence``) in the shipped model's metadata. Give ``--data`` twice (Mars and
Earth) to pool both sets, as the calibration is.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

from installs import child_env, load_average

from skyfix.detect import (PRESETS, DpOptions, NetOptions, combine_scores, detect_skyline, score_skyline,
                           scored_columns)
from skyfix.formats import read_skyline_json

#: ../shared/data beside the repository
DEV = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "marsscapes-dev"


def _read_rgb(path):
    import cv2

    from skyfix.formats.images import imread_upright

    im = imread_upright(path)  # as evaluate-detect reads it: upright by its EXIF orientation
    if im is None:
        raise SystemExit(f"cannot read {path}")
    if im.ndim == 3:
        im = cv2.cvtColor(im[..., :3], cv2.COLOR_BGR2RGB)
    return im


def _fmt(name, s, ms_per_mp):
    return (f"{name:>10s} {s['mean_abs_err_px']:8.2f} {100 * s['within_3px']:7.1f} "
            f"{100 * s['within_10px']:7.1f} {100 * s['false_rate']:7.2f} "
            f"{100 * s['missed_rate']:7.2f} {ms_per_mp:8.0f}")


HEADER = f"{'image':>10s} {'MAE px':>8s} {'<=3px%':>7s} {'<=10px%':>7s} {'false%':>7s} {'miss%':>7s} {'ms/MP':>8s}"


def run_set(pairs, method, out=sys.stdout, per_image=True, models=None, title="", image_options=None,
            **options):
    """pairs: iterable of (name, image array, truth Skyline); models: optional {name: SkyModel}
    (held-out models for cross-validation); image_options: optional {name: {option: value}} on
    top of ``options`` (the held-out network member of ``fuse``). Returns (pooled score, ms/MP)."""
    scores, t_tot, mp_tot, cols, no_sky = [], 0.0, 0.0, [], []
    print(f"-- method {method} {title}", file=out)
    print(HEADER, file=out)
    for name, img, truth in pairs:
        kw = dict(options)
        if models is not None:
            kw["model"] = models[name]
        kw.update((image_options or {}).get(name, {}))
        t0 = time.perf_counter()
        pred = detect_skyline(img, method=method, **kw)
        dt = time.perf_counter() - t0
        mp = img.shape[0] * img.shape[1] / 1e6
        s = score_skyline(pred, truth)
        scores.append(s)
        if not np.isfinite(np.asarray(truth.rows, float)).any():
            no_sky.append(s)
        cols.append(_column_outcomes(pred, truth))
        t_tot += dt
        mp_tot += mp
        if per_image:
            print(_fmt(name, s, 1000 * dt / mp), file=out, flush=True)
    tot = combine_scores(scores)
    print(_fmt("ALL", tot, 1000 * t_tot / max(mp_tot, 1e-9)), file=out, flush=True)
    if no_sky:
        print(f"   the {len(no_sky)} images without sky: "
              f"{100 * combine_scores(no_sky)['false_rate']:.2f} % of their columns claimed",
              file=out, flush=True)
    if cols:
        confidence_table(*map(np.concatenate, zip(*cols)), out=out)
    return tot, 1000 * t_tot / max(mp_tot, 1e-9)


def _column_outcomes(pred, truth):
    """Per scored column (those of ``score_skyline``) where the detection has a skyline: its
    confidence, whether the truth has one there, and whether the row is within 3 px of it."""
    rows, t = np.asarray(pred.rows, float), np.asarray(truth.rows, float)
    conf = (np.asarray(pred.confidence, float) if pred.confidence is not None
            else np.ones(rows.size))
    has = np.isfinite(rows) & scored_columns(pred, truth)
    return conf[has], np.isfinite(t[has]), np.abs(rows[has] - t[has]) <= 3.0


def confidence_table(conf, truth_has, within3, out=sys.stdout,
                     edges=(0.0, 0.3, 0.5, 0.7, 0.9, 1.0001)):
    """Does the per-column confidence mean something? Per confidence bin of the detected
    columns: how many, the share within 3 px of the truth and the share where the truth has no
    skyline (false skyline)."""
    print(f"   per-column confidence: {'bin':>11s} {'columns':>8s} {'<=3px%':>7s} {'false%':>7s}",
          file=out)
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (conf >= lo) & (conf < hi)
        if m.any():
            print(f"   {'':22s} {lo:4.2f}-{min(hi, 1.0):4.2f} {m.sum():8d} "
                  f"{100 * within3[m].mean():7.1f} {100 * (~truth_has[m]).mean():7.1f}",
                  file=out, flush=True)


def time_at_4mp(pairs, method, out=sys.stdout, **options):
    """The target is stated per 4-megapixel image, and the dev mosaics are 0.9-2.1 MP: time each
    one resampled to 4 MP (same aspect) and print the median and worst [s] against the 1 s
    target. Returns the median [s]."""
    import cv2

    times = []
    for _, img, _ in pairs:
        f = math.sqrt(4e6 / (img.shape[0] * img.shape[1]))
        big = cv2.resize(img, (round(img.shape[1] * f), round(img.shape[0] * f)),
                         interpolation=cv2.INTER_LINEAR)
        t0 = time.perf_counter()
        detect_skyline(big, method=method, **options)
        times.append(time.perf_counter() - t0)
    med, worst = float(np.median(times)), float(np.max(times))
    print(f"   {method}: per 4-MP image median {med:.2f} s, worst {worst:.2f} s over {len(times)} "
          f"images (median / target of 1 s = {med:.2f})", file=out, flush=True)
    return med


def peak_rss_4mp(img, out=sys.stdout, method="net", python=None):
    """Peak RSS [MB] of a fresh process that imports skyfix, reads one 4-MP image from a PNG and
    detects its skyline with ``method`` (the whole process: interpreter, imports, image, detector);
    also the peak before detecting (imports and the image). ``python``: the interpreter to run it
    with (default this one; a board install's, from ``scripts/board_install.sh``, measures the
    rover's footprint: no JIT compiler loaded, no scikit-learn)."""
    import subprocess
    import tempfile

    import cv2

    f = math.sqrt(4e6 / (img.shape[0] * img.shape[1]))
    big = cv2.resize(img, (round(img.shape[1] * f), round(img.shape[0] * f)))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "big.png"
        cv2.imwrite(str(path), big[..., ::-1] if big.ndim == 3 else big)
        # the process's own high-water mark (VmHWM): getrusage's ru_maxrss carries the parent's
        # peak across fork and exec, and this benchmark's parent holds every dev image; the heap
        # set up as `skyfix detect` sets it (skyfix.cli.heap)
        code = ("import re, sys; from skyfix.cli.heap import board_heap; board_heap(); "
                "import cv2; from skyfix.detect import detect_skyline; "
                "hwm = lambda: int(re.search(r'VmHWM:\\s+(\\d+)', "
                "open('/proc/self/status').read()).group(1)) / 1024; "
                "im = cv2.cvtColor(cv2.imread(sys.argv[1]), cv2.COLOR_BGR2RGB); "
                "print(hwm()); "
                f"detect_skyline(im, method='{method}'); "
                "print(hwm())")
        python = python or sys.executable
        env = child_env(python)
        # one warm-up call first: the figure is a detection's, not numba's first compilation
        # (a JIT install compiles once, then reads its cache)
        subprocess.run([python, "-c", code, str(path)], capture_output=True, text=True, env=env)
        r = subprocess.run([python, "-c", code, str(path)], capture_output=True, text=True, env=env)
    if r.returncode:
        print(f"   peak RSS measurement failed: {r.stderr.strip()[-300:]}", file=out)
        return None
    before, mb = (float(v) for v in r.stdout.strip().splitlines()[-2:])
    who = "" if python == sys.executable else f" ({python})"
    print(f"   {method}{who}: peak RSS of a process detecting one {big.shape[1]} x {big.shape[0]} image: "
          f"{mb:.0f} MB ({before:.0f} MB with the imports and the image, before detecting; "
          f"target 256 MB: ratio {mb / 256:.2f})", file=out, flush=True)
    return mb


def dev_pairs(folder):
    for truth_path in sorted(Path(folder).glob("*.skyline.json")):
        name = truth_path.name[: -len(".skyline.json")]
        yield name, _read_rgb(truth_path.with_name(name + ".png")), read_skyline_json(truth_path)


def sim_pairs(set_dir):
    """Every simulated frame under ``set_dir`` with its truth: the visible skyline (rocks
    included) where the simulator wrote one, else the terrain skyline."""
    for png in sorted(Path(set_dir).rglob("*.png")):
        stem = png.with_suffix("")
        vis, ter = Path(f"{stem}.visible.skyline.json"), Path(f"{stem}.skyline.json")
        truth = vis if vis.exists() else ter
        if truth.exists():
            yield f"{png.parent.name}/{png.stem}", _read_rgb(png), read_skyline_json(truth)


def site_fold_models(folder, names, n_folds=5, sim_dirs=(), sim_max_frames=10, grey=False):
    """{name: sky model trained without ``name``'s fold}: the labelled images of ``folder`` and the
    scored ``names`` dealt into ``n_folds`` folds by site (``sky_net_data.folds``: a Mars mosaic
    by its sol, anything else by its name), one model per fold by the recipe of
    ``scripts/train_sky_model.py``: each image and its sky-dominant crop, plus the simulated
    frames of ``sim_dirs`` (never held out: they are not dev images); ``grey``: on grey copies
    (its ``--grey``)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
    from train_sky_model import as_grey, read_labelled, simulated_frames, training_views
    from sky_net_data import folds

    from skyfix.detect.skymodel import fit_sky_model, training_pixels

    def views(img, sky):
        return [training_pixels(as_grey(im) if grey else im, sk)
                for _, im, sk in training_views(img, sky)]

    def site(name):
        # a MarsScapes name is SOL_N; anything else is its own site
        sol = name.split("_")[0]
        return f"mars:{sol}" if sol.isdigit() else f"web:{name}"

    parts = {name: views(img, sky) for name, img, sky in read_labelled(folder)}
    fold = folds({site(n) for n in [*parts, *names]}, n_folds)
    shared = [v for _, img, sky in simulated_frames(list(sim_dirs), sim_max_frames)
              for v in views(img, sky)]
    by_fold = {}
    for k in sorted({fold[site(n)] for n in names}):
        train = shared + [v for n, p in parts.items() if fold[site(n)] != k for v in p]
        by_fold[k], _ = fit_sky_model(train)
        print(f"   trained the model that holds fold {k} out", file=sys.stderr, flush=True)
    return {name: by_fold[fold[site(name)]] for name in names}


def degrade(img, how):
    """``img`` (RGB or grey uint8) as a user's pipeline may deliver it: ``grey`` (a camera without
    colour), ``jpeg:Q`` (JPEG at
    quality Q, the mosaic's black no-data border kept black, which JPEG smears), ``blur:S``
    (Gaussian blur of S px), ``denoise`` (a bilateral filter, as camera firmware smooths) or
    ``resample:F`` (down by F with area averaging, back up bilinearly)."""
    import cv2

    if "," in how:  # a chain, applied left to right
        for step in how.split(","):
            img = degrade(img, step)
        return img
    kind, _, arg = how.partition(":")
    if kind == "grey":
        return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
    if kind == "jpeg":
        black = (img == 0).all(axis=-1) if img.ndim == 3 else img == 0
        ok, buf = cv2.imencode(".jpg", img[..., ::-1] if img.ndim == 3 else img,
                               [cv2.IMWRITE_JPEG_QUALITY, int(arg or 75)])
        out = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
        out = out[..., ::-1].copy() if out.ndim == 3 else out
        out[black] = 0
        return out
    if kind == "blur":
        return cv2.GaussianBlur(img, (0, 0), float(arg or 1.0))
    if kind == "denoise":
        return cv2.bilateralFilter(img, 7, 20, 5)
    if kind == "resample":
        # down by F and back: a mosaic's sharp no-data border becomes a few pixels of grey ramp
        h, w = img.shape[:2]
        f = float(arg or 2.0)
        small = cv2.resize(img, (max(2, round(w / f)), max(8, round(h / f))), interpolation=cv2.INTER_AREA)
        return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    raise SystemExit(f"--degrade {how}: use grey, jpeg:Q, blur:S, denoise or resample:F (or a chain: grey,jpeg:70)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--methods", default="dp,bayes")
    ap.add_argument("--data", action="append", default=[],
                    help="labelled image folder (repeatable; default the Mars dev set)")
    ap.add_argument("--only", default="", help="comma-separated image names")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a detector option, e.g. --set w_region=0.1 (dp, fuse) or "
                         "--set net_pixels=150000 (net, also with --cv-net); each method takes "
                         "the keys its options have")
    ap.add_argument("--cv", action="store_true",
                    help="also a table cross-validated by site (retrains the sky model per fold)")
    ap.add_argument("--cv-folds", type=int, default=5, help="folds for --cv (default 5)")
    ap.add_argument("--sim", default="", help="folder of simulated sets (one sub-folder per set)")
    ap.add_argument("--cv-sim", default="",
                    help="training sims for --cv (the folder scripts/make_sky_sims.sh wrote)")
    ap.add_argument("--no-all", action="store_true", help="skip the shipped-model tables")
    ap.add_argument("--cv-net", default="", metavar="DIR",
                    help="score net with held-out fold models (see the module docstring)")
    ap.add_argument("--write-calibration", default="", metavar="MODEL.json",
                    help="with --cv-net: store the confidence calibration in this model metadata")
    ap.add_argument("--board-python", default="", metavar="PATH",
                    help="also measure the 4-MP peak RSS with this interpreter (a board install's, "
                         "scripts/board_install.sh DIR: DIR/bin/python)")
    ap.add_argument("--degrade", default="", metavar="grey|jpeg:Q|blur:S|denoise|resample:F",
                    help="degrade every image first (robustness to compression and smoothing)")
    args = ap.parse_args(argv)
    if args.degrade:
        degrade(np.zeros((8, 8, 3), np.uint8), args.degrade)  # refuse a bad spec before any work
    options = {}
    for kv in args.set:
        k, _, v = kv.partition("=")
        known = [o for o in (DpOptions(), NetOptions()) if hasattr(o, k)]
        if not known:
            raise SystemExit(f"--set {kv}: no dp or net option {k!r} (see skyfix.detect.DpOptions "
                             f"and NetOptions)")
        kind = type(getattr(known[0], k))
        # bool("False") is True: booleans are spelt out
        options[k] = v.lower() in ("1", "true", "yes") if kind is bool else kind(v)

    def options_of(method):
        """The --set options that ``method``'s options have (dp and fuse share DpOptions)."""
        return {k: v for k, v in options.items() if hasattr(PRESETS[method], k)}
    folders = [Path(d) for d in (args.data or [str(DEV)])]
    for folder in folders:
        if not folder.is_dir():
            raise SystemExit(f"no dev set at {folder}")
    folder = folders[0]
    only = set(filter(None, args.only.split(",")))
    pairs = [p for f in folders for p in dev_pairs(f) if not only or p[0] in only]
    folder_of = {t.name[: -len(".skyline.json")]: f.name
                 for f in folders for t in f.glob("*.skyline.json")}
    if args.degrade:
        pairs = [(n, degrade(im, args.degrade), t) for n, im, t in pairs]
    # warm up numba's cache so the first image is not charged for compilation
    detect_skyline(np.full((40, 40), 128, np.uint8))
    if not args.no_all:
        for m in args.methods.split(","):
            run_set(pairs, m, title="(shipped model)", **options_of(m))
            time_at_4mp(pairs, m, **options_of(m))
        for m in args.methods.split(","):
            peak_rss_4mp(pairs[0][1], method=m)
            if args.board_python:
                peak_rss_4mp(pairs[0][1], method=m, python=args.board_python)
    # fuse cross-validated: each image also gets the shipped network's member that held its fold
    # out (the ensemble's folds are these folds: sky_net_data.folds)
    member = {}
    if args.cv and "fuse" in args.methods.split(","):
        from skyfix.detect.net import load_sky_net

        member = load_sky_net().held_out_members()
        n_members = len(set(member.values()))
        if n_members != args.cv_folds:
            raise SystemExit(f"--cv with fuse needs --cv-folds {n_members}: the shipped network's "
                             f"members each held out one of {n_members} folds")
        # an image no member held out would be scored by the whole ensemble, which saw it
        missing = [p[0] for p in pairs if p[0] not in member]
        if missing:
            raise SystemExit("--cv with fuse: the shipped network names no member holding out "
                             + ", ".join(missing[:5]) + (" ..." if len(missing) > 5 else "")
                             + " (images it was not trained with the folds of): drop them")
    if args.cv:
        sim_dirs = sorted(p for p in Path(args.cv_sim).iterdir() if p.is_dir()) if args.cv_sim else []
        models = site_fold_models(folder, [p[0] for p in pairs], args.cv_folds, sim_dirs,
                                  grey="grey" in args.degrade.split(","))
        for m in [m for m in args.methods.split(",") if m in ("dp", "fuse")] or ["dp"]:
            per_image = {n: {"net_member": k} for n, k in member.items()} if m == "fuse" else {}
            for f in folders:  # one table per set: Mars mosaics and Earth photos fail differently
                title = f"{f.name} (sky model cross-validated, {args.cv_folds} folds by site"
                title += ", held-out network member)" if m == "fuse" else ")"
                run_set([p for p in pairs if folder_of[p[0]] == f.name], m, models=models,
                        title=title, image_options=per_image, **options_of(m))
    if args.cv_net:
        from cv_net import run_cv_net

        run_cv_net(pairs, Path(args.cv_net), write_calibration=args.write_calibration,
                   options=options_of("net"))
    if args.sim:
        for set_dir in sorted(p for p in Path(args.sim).iterdir() if p.is_dir()):
            sims = list(sim_pairs(set_dir))
            if args.degrade:
                sims = [(n, degrade(im, args.degrade), t) for n, im, t in sims]
            for m in args.methods.split(","):
                run_set(sims, m, per_image=False, title=f"(simulated {set_dir.name})",
                        **options_of(m))
    else:
        print("simulated sets: pass --sim DIR (DIR/REF, DIR/CLUT, ... written by "
              "skyfix.simulate.simulate_set)")


if __name__ == "__main__":
    print(f"load average at the start: {load_average()}", flush=True)
    main()
    print(f"load average at the end: {load_average()}")
