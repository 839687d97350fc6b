"""``fuse``'s options (the weight of the sky network in its region term, ``DpOptions.w_net``, and
any other ``DpOptions`` field), chosen inside the cross-validation.

    python benchmarks/choose_fuse_options.py --cv-sim SIMS [--set w_net=0,0.5,1,2] \
        [--set min_confidence=0.05,0.15] [--json OUT]

Every image of the two dev sets (``../shared/data/marsscapes-dev``, ``web-dev``) is detected with
``dp`` and each candidate set of options (every combination of the ``--set`` values; ``w_net``
times the network's log-odds in the region term, 1 being ``fuse``), by the sky classifier
trained without the image's fold (``bench_detect.site_fold_models``: the Mars mosaics and the
simulated frames of SIMS as ``scripts/make_sky_sims.sh`` writes them) and by the network member
that held the image out (the shipped model's ``held_out_by_member``). Then, fold by fold, the options are chosen on the
other four folds alone: the fewest wrong columns (claimed but more than 3 px off, claimed where the truth
has none, or missed), Mars and Earth averaged; the held-out table scores each fold with the options
its four other folds chose. So the figure printed last is the one a user can expect of the
selection itself, not of the best candidate in hindsight (printed too, per candidate).
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_detect import dev_pairs, site_fold_models  # noqa: E402
from cv_net import NO_SKY  # noqa: E402

from installs import load_average
from skyfix.detect import DpOptions, combine_scores, detect_skyline, score_skyline  # noqa: E402
from skyfix.detect.net import load_sky_net  # noqa: E402
from skyfix.detect.options import PRESETS, check_options  # noqa: E402
from skyfix.errors import ParameterError  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def wrong_share(scores) -> float:
    """Share of valid columns that are wrong: false, missed, or claimed more than 3 px off."""
    t = combine_scores(scores)
    bad = t["n_false"] + t["n_missed"] + t["n_both"] - t["n_within_3px"]
    return bad / t["n_valid"] if t["n_valid"] else 0.0


def line(label, scores: dict) -> str:
    """One set's pooled figures; ``scores``: image name -> :func:`score_skyline`."""
    t = combine_scores(scores.values())
    nosky = [s for n, s in scores.items() if n in NO_SKY]
    extra = (f", no-sky mosaics {100 * combine_scores(nosky)['false_rate']:.1f} % claimed"
             if nosky else "")
    return (f"{label}: {t['mean_abs_err_px']:.2f} px, {100 * t['within_3px']:.1f} % within 3 px, "
            f"false {100 * t['false_rate']:.2f} %, missed {100 * t['missed_rate']:.2f} %{extra}; "
            f"wrong {100 * wrong_share(list(scores.values())):.2f} %")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", action="append", default=[],
                    help="labelled image folders (default: marsscapes-dev and web-dev)")
    ap.add_argument("--cv-sim", required=True, help="training sims (scripts/make_sky_sims.sh SIMS)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=V1,V2,...",
                    help="candidate values of a DpOptions field (repeatable; every combination is "
                         "tried; default w_net=0,0.25,0.5,1,2)")
    ap.add_argument("--json", default="", help="write every image's scores here")
    args = ap.parse_args(argv)
    grid = {}
    for kv in args.set or ["w_net=0,0.25,0.5,1,2"]:
        key, _, vals = kv.partition("=")
        if not hasattr(DpOptions(), key) or not vals:
            raise SystemExit(f"--set {kv}: give a DpOptions field and its values, e.g. w_net=0.5,1")
        kind = type(getattr(DpOptions(), key))
        # bool("False") is True: booleans are spelt out
        grid[key] = [v.lower() in ("1", "true", "yes") if kind is bool else kind(v)
                     for v in vals.split(",")]
    cands = [dict(zip(grid, c)) for c in itertools.product(*grid.values())]
    for c in cands:  # a value out of range is refused now, not after the fold models are trained
        try:
            check_options(replace(PRESETS["fuse"], **c))
        except ParameterError as e:
            raise SystemExit(f"--set: {e}") from None
    folders = [Path(d) for d in args.data] or [DATA / "marsscapes-dev", DATA / "web-dev"]
    for f in folders:
        if not f.is_dir():
            raise SystemExit(f"no dev set at {f}")
    sims = sorted(p for p in Path(args.cv_sim).iterdir() if p.is_dir())
    if not sims:
        raise SystemExit(f"no simulated sets in {args.cv_sim}: run scripts/make_sky_sims.sh first")
    member = load_sky_net().held_out_members()
    pairs = [(f.name, *p) for f in folders for p in dev_pairs(f)]
    missing = [n for _, n, _, _ in pairs if n not in member]
    if missing:
        raise SystemExit("the shipped network names no member holding out "
                         + ", ".join(missing[:5]))
    t0 = time.time()
    # the sky classifier learns from the first set's labels (the Mars mosaics) and the sims, as
    # shipped and as bench_detect.py --cv trains it; the folds span every set's images
    models = site_fold_models(folders[0], [n for _, n, _, _ in pairs], 5, sims)
    res = [{} for _ in cands]  # candidate -> name -> score
    kind = {}
    for s, name, img, truth in pairs:
        kind[name] = s
        for i, c in enumerate(cands):
            sk = detect_skyline(img, method="dp", model=models[name], net_member=member[name],
                                **{"w_net": 1.0, **c})
            res[i][name] = score_skyline(sk, truth)
    print(f"detected {len(pairs)} images x {len(cands)} candidates in {time.time() - t0:.0f} s",
          file=sys.stderr)
    sets = sorted(set(kind.values()))

    def wrong(i, names):
        return np.mean([wrong_share([res[i][n] for n in names if kind[n] == s]) for s in sets])

    def label(i):
        return " ".join(f"{k} {v}" for k, v in cands[i].items())

    print("every image with one candidate (the choice not held out):")
    for i in range(len(cands)):
        for s in sets:
            print("  " + line(f"{label(i)} {s}", {n: sc for n, sc in res[i].items() if kind[n] == s}))
    chosen = {}
    for k in sorted(set(member.values())):
        train = [n for n in kind if member[n] != k]
        chosen[k] = min(range(len(cands)), key=lambda i: wrong(i, train))
    print("chosen by the other four folds: "
          + ", ".join(f"fold {k}: {label(i)}" for k, i in chosen.items()))
    print("held out (each fold with its own choice):")
    held = {n: res[chosen[member[n]]][n] for n in kind}
    for s in sets:
        print("  " + line(s, {n: sc for n, sc in held.items() if kind[n] == s}))
    if args.json:
        Path(args.json).write_text(json.dumps(
            {"candidates": cands, "chosen": chosen, "member": member, "scores": res},
            default=float))


if __name__ == "__main__":
    print(f"load average at the start: {load_average()}", flush=True)
    main()
    print(f"load average at the end: {load_average()}")
