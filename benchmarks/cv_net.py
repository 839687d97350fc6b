"""Cross-validated scoring of the ``net`` detector (``bench_detect.py --cv-net DIR``).

Every figure comes from a model that did not see the image: fold models from
``scripts/train_sky_net.py --folds N --fold K`` list the images they held out. The per-column
confidence calibration (isotonic: share of claimed columns within 3 px of the truth, against the
raw confidence) and the ``min_confidence`` cut are fitted on the other folds' columns and applied
to the held-out fold.
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from skyfix._io import write_json
from skyfix.detect import NetOptions, combine_scores, detect_skyline, score_skyline, scored_columns
from skyfix.detect.net import finish_columns
from skyfix.formats import Skyline

#: the no-sky mosaics of the Mars dev set (shared/data/README.md)
NO_SKY = {"372_1", "385_1", "389_2", "431_2", "127_1", "147_1", "344_2", "365_2", "371_2", "388_2",
          "389_1", "404_2", "439_3", "463_1", "465_2", "521_1"}
THRESHOLDS = (0.0, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7)


def isotonic(x, y, w=None):
    """Pool-adjacent-violators: the non-decreasing fit of ``y`` on ``x`` (least squares, weights
    ``w``). Returns (knots x, fitted y) at the pooled blocks' mean x, for ``np.interp``."""
    order = np.argsort(x, kind="stable")
    x, y = np.asarray(x, float)[order], np.asarray(y, float)[order]
    w = np.ones_like(x) if w is None else np.asarray(w, float)[order]
    vals, wts, xs = [], [], []
    for xi, yi, wi in zip(x, y, w):
        vals.append(yi)
        wts.append(wi)
        xs.append(xi * wi)
        while len(vals) > 1 and vals[-2] > vals[-1]:
            v2, w2, x2 = vals.pop(), wts.pop(), xs.pop()
            vals[-1] = (vals[-1] * wts[-1] + v2 * w2) / (wts[-1] + w2)
            xs[-1] += x2
            wts[-1] += w2
    kx = np.array(xs) / np.array(wts)
    return kx, np.array(vals)


def thin_knots(kx, ky, n=40):
    """At most ``n`` knots (evenly in rank), keeping the ends."""
    if kx.size <= n:
        return kx, ky
    idx = np.unique(np.linspace(0, kx.size - 1, n).round().astype(int))
    return kx[idx], ky[idx]


def _fold_models(folder: Path) -> dict:
    """{image name: fold model path} from each fold's ``held_out`` list."""
    out = {}
    for meta_path in sorted(folder.glob("fold_*.json")):
        onnx = meta_path.with_suffix(".onnx")
        for name in json.loads(meta_path.read_text()).get("held_out", []):
            out[name] = onnx
    return out


def _kind(name):
    return "web" if name.startswith("GoogleImage") else "mars"


def _finish(rows, conf, valid, opt, f=1):
    rows, conf = rows.copy(), conf.copy()
    finish_columns(rows, conf, valid, opt, f)
    return rows, conf


def run_cv_net(pairs, folder: Path, *, write_calibration: str = "", out=sys.stdout, options=None):
    """Score ``net`` on ``pairs`` (name, image, truth), each image by the fold model of ``folder``
    that held it out; ``options``: NetOptions fields for every run. The confidence cut is chosen
    here, on the other folds; the network runs without it and without the run hysteresis, which
    are applied afterwards (the hysteresis as ``options`` gives it, else its default). Returns
    {name: (score, rows, confidence)}."""
    models = _fold_models(folder)
    missing = [n for n, _, _ in pairs if n not in models]
    if missing:
        raise SystemExit(f"no fold model in {folder} held out {', '.join(missing[:5])}"
                         f"{' ...' if len(missing) > 5 else ''}: train every fold first")
    recs = []  # per image: name, fold, truth, rows, raw conf, col validity
    for name, img, truth in pairs:
        model = models[name]
        sk = detect_skyline(img, method="net", model=model, **{**(options or {}), "min_confidence": 0.0,
                                                               "min_run": 0, "anchor_conf": 0.0})
        recs.append(dict(name=name, fold=model.stem, kind=_kind(name), truth=truth,
                         rows=np.asarray(sk.rows, float), raw=np.asarray(sk.confidence, float),
                         valid=np.asarray(sk.valid, bool)))
    folds = sorted({r["fold"] for r in recs})

    def columns(rs):
        """Claimed, scored columns: (raw confidence, within 3 px of a true skyline)."""
        c, ok = [], []
        for r in rs:
            pred = Skyline(rows=r["rows"], width=r["rows"].size, height=1, valid=r["valid"])
            has = np.isfinite(r["rows"]) & scored_columns(pred, r["truth"])
            t = np.asarray(r["truth"].rows, float)[has]
            c.append(r["raw"][has])
            ok.append(np.isfinite(t) & (np.abs(r["rows"][has] - t) <= 3.0))
        return np.concatenate(c), np.concatenate(ok)

    def scores_at(rs, cal, thr):
        res = {}
        opt = replace(NetOptions(**(options or {})), min_confidence=thr)
        for r in rs:
            conf = np.interp(r["raw"], *cal)
            rows, conf = _finish(r["rows"], conf, r["valid"], opt)
            s = score_skyline(Skyline(rows=rows, width=rows.size, height=1, confidence=conf,
                                      valid=r["valid"]), r["truth"])
            res[r["name"]] = (s, rows, conf)
        return res

    # held out: calibration and threshold from the other folds
    held = {}
    cal_cols = []
    chosen = {}
    for fo in folds:
        train = [r for r in recs if r["fold"] != fo]
        test = [r for r in recs if r["fold"] == fo]
        cal = isotonic(*columns(train))
        best = None
        for thr in THRESHOLDS:
            tot = combine_scores([s for s, _, _ in scores_at(train, cal, thr).values()])
            key = tot["false_rate"] + tot["missed_rate"]
            if best is None or key < best[0] - 1e-12:
                best = (key, thr)
        chosen[fo] = best[1]
        held.update(scores_at(test, cal, best[1]))
        c_raw, ok = columns(test)
        cal_cols.append((np.interp(c_raw, *cal), ok))
    print(f"-- net, cross-validated ({len(folds)} folds by sol / by photo; calibration and "
          f"min_confidence from the other folds: {', '.join(f'{k} {v}' for k, v in chosen.items())})"
          + "".join(f"; {k}={v}" for k, v in (options or {}).items()), file=out)
    _report(recs, held, out)
    print("   the same without the confidence cut (raw path, every column the path claims):", file=out)
    raw_scores = {r["name"]: (score_skyline(Skyline(rows=r["rows"], width=r["rows"].size, height=1,
                                                    valid=r["valid"]), r["truth"]), None, None)
                  for r in recs}
    _report(recs, raw_scores, out, per_image=False)
    conf = np.concatenate([c for c, _ in cal_cols])
    ok = np.concatenate([o for _, o in cal_cols])
    print("   reliability of the calibrated per-column confidence (held out), claimed columns:",
          file=out)
    print(f"   {'confidence':>12s} {'columns':>8s} {'mean conf':>9s} {'<=3px%':>7s}", file=out)
    for lo, hi in zip((0, .2, .4, .6, .8, .9, .95), (.2, .4, .6, .8, .9, .95, 1.0001)):
        m = (conf >= lo) & (conf < hi)
        if m.any():
            print(f"   {lo:5.2f}-{min(hi, 1):4.2f} {m.sum():8d} {conf[m].mean():9.3f} {100 * ok[m].mean():7.1f}",
                  file=out)
    if write_calibration:
        cal = thin_knots(*isotonic(*columns(recs)))
        best = min(THRESHOLDS, key=lambda t: (lambda tot: tot["false_rate"] + tot["missed_rate"])(
            combine_scores([s for s, _, _ in scores_at(recs, cal, t).values()])))
        path = Path(write_calibration)
        meta = json.loads(path.read_text()) if path.is_file() else {}
        meta["calibration"] = {"raw": [round(float(v), 5) for v in cal[0]],
                               "p_within_3px": [round(float(v), 5) for v in cal[1]],
                               "fitted_on": f"cross-validated columns of {len(recs)} images "
                                            f"({folder.name}), isotonic",
                               "min_confidence_chosen": best}
        write_json(path, meta)  # atomic: a torn file broke every net and fuse detection
        print(f"   wrote the calibration ({cal[0].size} knots) to {path}; min_confidence on all "
              f"folds: {best}", file=out)
    return held


def _report(recs, scored, out, per_image=True):
    for kind in ("mars", "web"):
        rs = [r for r in recs if r["kind"] == kind]
        if not rs:
            continue
        ss = [scored[r["name"]][0] for r in rs]
        tot = combine_scores(ss)
        # every image whose truth has a skyline counts: one where nothing was claimed (no mean)
        # fails the bar, and was left out of the count
        means = [s["mean_abs_err_px"] for r, s in zip(rs, ss) if r["name"] not in NO_SKY]
        good = sum(bool(np.isfinite(m) and m <= 5.0) for m in means)
        line = (f"   {kind}: {len(rs)} images, mean {tot['mean_abs_err_px']:.2f} px, "
                f"{100 * tot['within_3px']:.1f} % within 3 px, {100 * tot['within_10px']:.1f} % within 10, "
                f"false {100 * tot['false_rate']:.2f} %, missed {100 * tot['missed_rate']:.2f} %, "
                f"images with mean <= 5 px {good}/{len(means)}")
        nosky = [s for r, s in zip(rs, ss) if r["name"] in NO_SKY]
        if nosky:
            c = combine_scores(nosky)
            line += f"; the {len(nosky)} no-sky mosaics: {100 * c['false_rate']:.2f} % of columns claimed"
        print(line, file=out, flush=True)
        if per_image:
            for r, s in zip(rs, ss):
                if not (s["mean_abs_err_px"] <= 3.0) or s["false_rate"] > 0.01 or s["missed_rate"] > 0.05:
                    print(f"      {r['name']:>16s} ({r['fold']}): {s['mean_abs_err_px']:7.2f} px, "
                          f"{100 * s['within_3px']:5.1f} % <= 3 px, false {100 * s['false_rate']:5.1f} %, "
                          f"missed {100 * s['missed_rate']:5.1f} %", file=out)
