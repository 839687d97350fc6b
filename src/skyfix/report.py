"""Evaluation results: the per-case record, tables in the source study's form, figures, and one
self-contained ``report.html``.

Nothing here runs the pipeline (that is :mod:`skyfix.evaluate`); it turns results into evidence.
"""

from __future__ import annotations

import base64
import csv
import html
import math
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np

from ._io import atomic_path
from .north import true_heading_deg, wrap_deg
from .optional import pyplot

#: what "correct" means per scenario: position error [m] and heading error [deg] at most
TOLERANCES = {1: (5.0, 2.0), 2: (1.0, 1.0), 3: (math.inf, 1.0)}
#: each scenario's time budget on the rover [s] and the rover's slowness relative to this machine
BUDGET_S = {1: 88_775.0, 2: 3_600.0, 3: 300.0}  # 1 sol, 1 h, 5 min
ROVER_SLOWDOWN = 30.0


@dataclass
class CaseResult:
    """One evaluated case. Angles [deg], positions [m], times [s], memory [MB]; NaN when unknown.

    Headings come in both norths (``conventions.md``, "Units and angles"): ``truth_yaw_deg`` and
    ``fix_grid_heading_deg`` are from grid north (the simulator's and the localiser's frame);
    ``truth_heading_deg`` and ``fix_heading_deg`` (properties) are from true north, each the grid
    one plus the meridian convergence at its own position (``truth_meridian_convergence_deg``,
    ``meridian_convergence_deg`` at the fix; NaN, and the true heading the grid one, where the
    CRS has no true north). The heading error is grid minus grid: the rotation the localiser got
    wrong, free of the convergence's change between the truth's and the fix's positions."""

    case: str
    set: str
    scenario: int
    truth_x: float
    truth_y: float
    truth_yaw_deg: float
    truth_meridian_convergence_deg: float = math.nan
    truth_pitch_deg: float = 0.0
    truth_roll_deg: float = 0.0
    prior_offset_m: float = 0.0
    fix_x: float = math.nan
    fix_y: float = math.nan
    fix_grid_heading_deg: float = math.nan
    meridian_convergence_deg: float = math.nan
    fix_pitch_deg: float = math.nan
    fix_roll_deg: float = math.nan
    confidence: float = math.nan
    score: float = math.nan
    position_sigma_m: float = math.nan
    heading_sigma_deg: float = math.nan
    status: str = "ok"
    time_simulate_s: float = math.nan
    time_profile_s: float = math.nan
    time_locate_s: float = math.nan
    peak_rss_mb: float = math.nan
    map_offset_x_m: float = 0.0
    map_offset_y_m: float = 0.0
    extra: dict = field(default_factory=dict)

    @property
    def truth_heading_deg(self) -> float:
        """The truth's heading [deg] from true north."""
        return true_heading_deg(self.truth_yaw_deg, self.truth_meridian_convergence_deg)

    @property
    def fix_heading_deg(self) -> float:
        """The fix's heading [deg] from true north (NaN without a fix)."""
        if not math.isfinite(self.fix_grid_heading_deg):
            return math.nan
        return true_heading_deg(self.fix_grid_heading_deg, self.meridian_convergence_deg)

    @property
    def error_x_m(self) -> float:
        return self.fix_x - self.truth_x

    @property
    def error_y_m(self) -> float:
        return self.fix_y - self.truth_y

    @property
    def position_error_m(self) -> float:
        return math.hypot(self.error_x_m, self.error_y_m)

    @property
    def error_map_x_m(self) -> float:
        """[m] the fix's x error beyond the simulated misregistration (see position_error_map_m)."""
        return self.error_x_m - self.map_offset_x_m

    @property
    def error_map_y_m(self) -> float:
        """[m] the fix's y error beyond the simulated misregistration."""
        return self.error_y_m - self.map_offset_y_m

    @property
    def position_error_map_m(self) -> float:
        """Distance [m] from the fix to where the truth's terrain lies on the map: the error beyond
        a simulated misregistration of the map (which no localiser can undo); the plain error
        when the world is the map. What "correct", the tables, the figures and the calibration
        cases count; results.csv keeps the plain error beside it."""
        return math.hypot(self.error_map_x_m, self.error_map_y_m)

    @property
    def heading_error_deg(self) -> float:
        return float(abs(wrap_deg(self.fix_grid_heading_deg - self.truth_yaw_deg)))

    @property
    def correct(self) -> bool:
        pos_tol, head_tol = TOLERANCES[self.scenario]
        if self.status != "ok" or not math.isfinite(self.fix_grid_heading_deg):
            return False
        pos_ok = self.scenario == 3 or self.position_error_map_m <= pos_tol
        return bool(pos_ok and self.heading_error_deg <= head_tol)


def _csv_fields() -> list[str]:
    # each true-north heading (a property) sits just before its grid heading and convergence
    names = []
    for f in fields(CaseResult):
        if f.name == "truth_yaw_deg":
            names.append("truth_heading_deg")
        elif f.name == "fix_grid_heading_deg":
            names.append("fix_heading_deg")
        if f.name != "extra":
            names.append(f.name)
    return names + ["error_x_m", "error_y_m", "position_error_m", "position_error_map_m",
                    "heading_error_deg", "correct"]


#: results.csv's columns, in order: CaseResult's fields, its true headings and its errors
CSV_FIELDS = _csv_fields()


def write_results_csv(results: list[CaseResult], path) -> Path:
    path = Path(path)
    with atomic_path(path, suffix=".csv") as tmp:
        with open(tmp, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=CSV_FIELDS)
            w.writeheader()
            for r in results:
                row = {k: v for k, v in asdict(r).items() if k != "extra"}
                row.update(truth_heading_deg=r.truth_heading_deg, fix_heading_deg=r.fix_heading_deg,
                           error_x_m=r.error_x_m, error_y_m=r.error_y_m,
                           position_error_m=r.position_error_m,
                           position_error_map_m=r.position_error_map_m,
                           heading_error_deg=r.heading_error_deg, correct=r.correct)
                w.writerow({k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in row.items()})
    return path


def read_results_csv(path) -> list[CaseResult]:
    """The cases of a ``results.csv`` (the computed columns are recomputed, not read)."""
    out = []
    names = {f.name: f.type for f in fields(CaseResult)}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            if "fix_grid_heading_deg" not in row and "fix_heading_deg" in row:
                # written before the true-north columns: its fix_heading_deg was the grid heading
                row["fix_grid_heading_deg"] = row.pop("fix_heading_deg")
            kw = {}
            for k, v in row.items():
                if k not in names or k == "extra":
                    continue
                kw[k] = v if k in ("case", "set", "status") else (int(v) if k == "scenario" else float(v))
            out.append(CaseResult(**kw))
    return out


def _pct(a, q):
    a = np.asarray(a, float)
    a = a[np.isfinite(a)]
    return float(np.percentile(a, q)) if a.size else math.nan


def summary_rows(results: list[CaseResult]) -> list[dict]:
    """One row per set (and 'all'): the source study's columns plus success and calibration."""
    rows = []
    sets = sorted({r.set for r in results}) + ["all"]
    for s in sets:
        rs = [r for r in results if s == "all" or r.set == s]
        if not rs:
            continue
        ok = [r for r in rs if r.status == "ok"]
        conf_hi = [r for r in ok if r.confidence >= 0.9]
        # scenario 3's position is the rough one it was given, not a result: no position columns
        pos = [r for r in ok if r.scenario != 3]
        rows.append({
            "set": s, "cases": len(rs), "failed": len(rs) - len(ok),
            "correct_pct": 100.0 * np.mean([r.correct for r in rs]),
            "err_x_med_m": _pct([abs(r.error_map_x_m) for r in pos], 50),
            "err_y_med_m": _pct([abs(r.error_map_y_m) for r in pos], 50),
            "pos_err_med_m": _pct([r.position_error_map_m for r in pos], 50),
            "pos_err_p95_m": _pct([r.position_error_map_m for r in pos], 95),
            "head_err_med_deg": _pct([r.heading_error_deg for r in ok], 50),
            "head_err_p95_deg": _pct([r.heading_error_deg for r in ok], 95),
            "score_med": _pct([r.score for r in ok], 50),
            "conf_ge_0.9": len(conf_hi),
            "correct_if_conf_ge_0.9_pct": (100.0 * np.mean([r.correct for r in conf_hi]) if conf_hi else math.nan),
            "time_med_s": _pct([r.time_profile_s + r.time_locate_s for r in ok], 50),
        })
    return rows


def sigma_coverage_rows(results: list[CaseResult]) -> list[dict]:
    """One row per set (and 'all'): how often the reported 1-sigmas cover the errors. Position:
    the error beyond the simulated misregistration within 1 and 2 ``position_sigma_m`` (a radial
    sigma, the square root of the covariance's trace: 63 % and 98 % for a round Gaussian);
    heading within 1 and 2 ``heading_sigma_deg`` (68 % and 95 %). A sigma that allows for a wrong
    basin (:mod:`skyfix.pose.basin_sigma`) claims the 1-sigma share only: at a low confidence
    twice it holds less than a Gaussian's. Only located cases with a finite sigma count
    (scenario 3 reports no position sigma)."""
    rows = []
    for s in sorted({r.set for r in results}) + ["all"]:
        ok = [r for r in results if (s == "all" or r.set == s) and r.status == "ok"]
        if not ok:
            continue
        row = {"set": s}
        for key, err, sig in (("pos", "position_error_map_m", "position_sigma_m"),
                              ("head", "heading_error_deg", "heading_sigma_deg")):
            pairs = [(getattr(r, err), getattr(r, sig)) for r in ok
                     if math.isfinite(getattr(r, sig)) and math.isfinite(getattr(r, err))]
            row[f"{key}_cases"] = len(pairs)
            for k in (1, 2):
                row[f"{key}_within_{k}_sigma_pct"] = (
                    100.0 * float(np.mean([e <= k * g for e, g in pairs])) if pairs else math.nan)
        rows.append(row)
    return rows


def heading_vs_prior_rows(results: list[CaseResult]) -> list[dict]:
    """Scenario 3: heading error against the prior position error. A failed case counts in its
    offset's cases, as within neither bar (the shares were of the successes alone)."""
    rows = []
    for off in sorted({round(r.prior_offset_m, 3) for r in results}):
        rs = [r for r in results if round(r.prior_offset_m, 3) == off]
        errs = [r.heading_error_deg for r in rs if r.status == "ok"]

        def share(bar, rs=rs):
            return 100.0 * np.mean([r.status == "ok" and r.heading_error_deg <= bar for r in rs])
        rows.append({"prior_offset_m": off, "cases": len(rs), "failed": len(rs) - len(errs),
                     "head_err_med_deg": _pct(errs, 50), "head_err_p95_deg": _pct(errs, 95),
                     "within_1deg_pct": share(1.0), "within_2deg_pct": share(2.0)})
    return rows


def reliability_rows(results: list[CaseResult], edges=(0.0, 0.3, 0.5, 0.7, 0.9, 1.0001)) -> list[dict]:
    """Confidence bins: mean stated confidence vs observed share correct."""
    rows = []
    conf = np.array([r.confidence if math.isfinite(r.confidence) else 0.0 for r in results])
    corr = np.array([r.correct for r in results])
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (conf >= lo) & (conf < hi)
        rows.append({"confidence_bin": f"{lo:.1f}-{min(hi, 1.0):.1f}", "cases": int(m.sum()),
                     "mean_confidence": float(conf[m].mean()) if m.any() else math.nan,
                     "observed_correct": float(corr[m].mean()) if m.any() else math.nan})
    return rows


#: units written as the last word of a column name, and how a reader sees them
_UNITS = {"m": "m", "deg": "deg", "s": "s", "pct": "%", "mb": "MB", "px": "px"}


#: abbreviations of the tables' column names, spelled out
_WORDS = {"ge": ">=", "le": "<=", "med": "median", "conf": "confidence", "err": "error",
          "head": "heading", "pos": "position", "pct": "%"}


def header_label(name: str) -> str:
    """A column name as a person reads it: ``head_err_med_deg`` -> ``heading error median [deg]``,
    ``correct_if_conf_ge_0.9_pct`` -> ``correct if confidence >= 0.9 [%]``."""
    words = str(name).split("_")
    unit = _UNITS.get(words[-1].lower()) if len(words) > 1 else None
    if unit:
        words = words[:-1]
    text = " ".join(_WORDS.get(w, w) for w in words)
    return f"{text} [{unit}]" if unit else text


def case_rows(results: list[CaseResult]) -> list[dict]:
    """One row per case: what was found, how far from the truth (beyond a simulated
    misregistration, as "correct" counts it), how sure."""
    rows = []
    for r in results:
        rows.append({"set": r.set, "case": r.case, "status": r.status,
                     "position_error_m": r.position_error_map_m if r.scenario != 3 else math.nan,
                     "heading_error_deg": r.heading_error_deg, "confidence": r.confidence,
                     "position_sigma_m": r.position_sigma_m, "heading_sigma_deg": r.heading_sigma_deg,
                     "correct": "yes" if r.correct else "no"})
    return rows


#: figure file name prefix -> caption
FIGURE_CAPTIONS = {
    "track": "The traverse over a hillshade: truth, odometry alone, the fused track, its position "
             "fixes and any operator requests.",
    "errors": "Position and heading error against the distance driven: fused, and odometry alone.",
    "error_cdf": "Cumulative share of cases against the error the scenario is judged on (the "
                 "position's beyond any simulated misregistration; the heading's in scenario 3), "
                 "per set; a failed case counts as never within.",
    "reliability": "Confidence reliability: the share of correct fixes per confidence bin "
                   "(on the diagonal when the confidence is calibrated).",
    "overlay": "A case's measured profile (its legend says whether detected or the simulator's "
               "exact skyline) over the DEM's skyline at the fix and at the truth.",
}


def figure_caption(path) -> str:
    stem = Path(path).stem
    for prefix, text in FIGURE_CAPTIONS.items():
        if stem.startswith(prefix):
            extra = stem[len(prefix):].strip("_").replace("_", " ")
            return f"{text} ({extra})" if extra else text
    return stem.replace("_", " ")


def format_table(rows: list[dict], fmt: str = "text") -> str:
    """Rows of dicts as an aligned text table, Markdown, or HTML (HTML headers as a person reads
    them: :func:`header_label`)."""
    if not rows:
        return ""
    cols = list(rows[0])

    def cell(v):
        if isinstance(v, float):
            return "-" if not math.isfinite(v) else (f"{v:.2f}" if abs(v) < 1000 else f"{v:.0f}")
        return str(v)

    body = [[cell(r[c]) for c in cols] for r in rows]
    if fmt == "html":
        head = "".join(f"<th>{html.escape(header_label(c))}</th>" for c in cols)
        trs = "".join("<tr>" + "".join(f"<td>{html.escape(v)}</td>" for v in b) + "</tr>" for b in body)
        return f"<table><thead><tr>{head}</tr></thead><tbody>{trs}</tbody></table>"
    if fmt == "markdown":
        lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
        return "\n".join(lines + ["| " + " | ".join(b) + " |" for b in body])
    widths = [max(len(c), *(len(b[i]) for b in body)) for i, c in enumerate(cols)]
    lines = ["  ".join(c.rjust(w) for c, w in zip(cols, widths))]
    lines += ["  ".join(v.rjust(w) for v, w in zip(b, widths)) for b in body]
    return "\n".join(lines)


# --- figures ---------------------------------------------------------------------------------------

def save_figure(fig, path) -> Path:
    """Write ``fig`` as PNG to ``path`` atomically (110 dpi) and close it."""
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110, format="png", bbox_inches="tight")  # legends sit outside the axes
    pyplot().close(fig)
    return Path(path)


def plot_error_cdfs(results: list[CaseResult], path, scenario: int) -> Path:
    """Empirical CDF of the position error (heading error for scenario 3) per set."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 4))
    key = "heading_error_deg" if scenario == 3 else "position_error_map_m"
    errs = {s: np.sort([getattr(r, key) if r.status == "ok" else np.inf for r in results
                        if r.set == s]) for s in sorted({r.set for r in results})}
    # the axis starts a decade below the smallest error (a fixed 0.1 m hid a set whose errors
    # all lay below it), and every curve starts there at 0
    pos = [v for e in errs.values() for v in e if np.isfinite(v) and v > 0]
    lo = min(0.01 if scenario == 3 else 0.1, 10 ** np.floor(np.log10(min(pos))) if pos else 1.0)
    for s, e in errs.items():
        y = np.arange(1, e.size + 1) / e.size
        ax.step(np.r_[lo, np.clip(np.where(np.isfinite(e), e, 1e6), lo, None)], np.r_[0.0, y],
                where="post", label=f"{s} ({e.size})")
    tol = TOLERANCES[scenario][1 if scenario == 3 else 0]
    ax.axvline(tol, color="k", ls="--", lw=1, label=f"requirement {tol:g}")
    ax.set_xscale("log")
    ax.set_xlim(lo, 1000)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("heading error [deg]" if scenario == 3 else "position error [m]")
    ax.set_ylabel("share of cases")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    ax.set_title(f"scenario {scenario}: error CDF per set")
    fig.tight_layout()
    return save_figure(fig, path)


def plot_reliability(results: list[CaseResult], path) -> Path:
    """Reliability diagram of the confidence (stated vs observed share correct)."""
    plt = pyplot()
    rows = reliability_rows(results)
    fig, ax = plt.subplots(figsize=(4.5, 4.5))
    ax.plot([0, 1], [0, 1], "k--", lw=1, label="perfect calibration")
    mc = [r["mean_confidence"] for r in rows if r["cases"]]
    oc = [r["observed_correct"] for r in rows if r["cases"]]
    n = [r["cases"] for r in rows if r["cases"]]
    ax.plot(mc, oc, "o-", color="tab:blue", label="skyfix")
    for x, y, k in zip(mc, oc, n):
        ax.annotate(str(k), (x, y), textcoords="offset points", xytext=(4, -10), fontsize=7)
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("stated confidence")
    ax.set_ylabel("observed share correct")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    ax.set_title("confidence reliability (cases per bin)")
    fig.tight_layout()
    return save_figure(fig, path)


# --- the report ------------------------------------------------------------------------------------

def timing_rows(results: list[CaseResult], scenario: int) -> list[dict]:
    """Per-stage median time here, extrapolated to the rover CPU, against the scenario's budget."""
    ok = [r for r in results if r.status == "ok"]
    rows = []
    for stage, key in (("profile (detect + project)", "time_profile_s"), ("locate / heading", "time_locate_s")):
        t = _pct([getattr(r, key) for r in ok], 50)
        rows.append({"stage": stage, "median_here_s": t, "rover_est_s": t * ROVER_SLOWDOWN,
                     "budget_s": BUDGET_S[scenario],
                     "share_of_budget_pct": 100.0 * t * ROVER_SLOWDOWN / BUDGET_S[scenario]})
    return rows


def memory_rows(results: list[CaseResult]) -> list[dict]:
    """The evaluating process's peak resident memory [MB] over the cases (the whole process,
    simulation included: not the board's budget, which ``benchmarks/bench_board.py`` measures)."""
    ok = [r for r in results if r.status == "ok"]
    return [{"what": "peak RSS of the evaluating process, max over the cases",
             "max_mb": _pct([r.peak_rss_mb for r in ok], 100)}]


def _img(path: Path, root: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    rel = html.escape(str(path.relative_to(root)))
    cap = html.escape(figure_caption(path))
    return (f'<figure><a href="{rel}"><img src="data:image/png;base64,{data}" alt="{cap}"></a>'
            f"<figcaption>{cap}</figcaption></figure>")


def write_report_html(out_dir, *, title: str, intro: str, sections: list[tuple[str, str]],
                      figures: list[Path], command: str) -> Path:
    """One self-contained HTML page (figures embedded, and linked to their PNG files)."""
    from . import __version__

    out_dir = Path(out_dir)
    parts = [f"<h2>{html.escape(h)}</h2>{body}" for h, body in sections]
    figs = "".join(_img(Path(p), out_dir) for p in figures if Path(p).exists())
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>body{{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}}
table{{border-collapse:collapse;margin:1em 0;font-size:13px}}th,td{{border:1px solid #ccc;padding:3px 7px;text-align:right}}
th{{background:#f3f3f3}}figure{{display:inline-block;margin:.5em;vertical-align:top;max-width:100%}}img{{max-width:100%;max-height:640px}}
figcaption{{font-size:11px;color:#666}}code{{background:#f5f5f5;padding:1px 4px}}</style></head><body>
<h1>{html.escape(title)}</h1><p>{intro}</p><p>skyfix {html.escape(__version__)}. Regenerate with <code>{html.escape(command)}</code>.</p>
{''.join(parts)}<h2>Figures</h2>{figs}</body></html>"""
    path = out_dir / "report.html"
    with atomic_path(path, suffix=".html") as tmp:
        tmp.write_text(page)
    return path
