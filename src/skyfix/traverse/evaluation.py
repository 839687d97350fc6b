"""``skyfix evaluate --scenario traverse``: simulate a traverse, fuse it, and report the errors
against the truth beside odometry alone (tables, the track map, error against distance)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np


def traverse_errors(rows, trav, convergence):
    """Per stop: distance driven by the truth [m], fused position and heading errors [m, deg], and
    odometry alone's [m, deg]. Positions are compared with where the truth's terrain lies on the
    map (the truth plus the simulated map offset: no localiser can undo a misregistration)."""
    from ..north import true_heading_deg
    from .ekf import wrap_deg
    from .simulate import map_offset_of, odometry_only

    ox, oy = map_offset_of(trav)
    truth = [{**t, "x": t["x"] + ox, "y": t["y"] + oy} for t in trav.truth]
    odo = odometry_only(trav, convergence)
    dist = np.r_[0.0, np.cumsum([math.hypot(b["x"] - a["x"], b["y"] - a["y"])
                                 for a, b in zip(truth[:-1], truth[1:])])]
    pe = np.array([math.hypot(r["x"] - t["x"], r["y"] - t["y"]) for r, t in zip(rows, truth)])
    he = np.abs(wrap_deg([r["heading_deg"] - t["heading_deg"] for r, t in zip(rows, truth)]))
    ope = np.array([math.hypot(o[0] - t["x"], o[1] - t["y"]) for o, t in zip(odo, truth)])
    ohe = np.abs(wrap_deg([true_heading_deg(o[2], convergence(o[0], o[1])) - t["heading_deg"]
                           for o, t in zip(odo, truth)]))
    return dist[: len(rows)], pe, he, ope[: len(rows)], ohe[: len(rows)]


def plot_errors(path, dist, pe, he, ope, ohe, fixes) -> Path:
    """Position and heading error against the distance driven: fused and odometry alone."""
    from .._io import save_figure
    from ..optional import pyplot

    plt = pyplot()
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    a1.plot(dist, ope, "--", color="tab:orange", label="odometry alone")
    a1.plot(dist, pe, "-", color="tab:blue", label="fused")
    a1.plot(dist[fixes], pe[fixes], "o", color="tab:green", label="after a position fix")
    a1.set_ylabel("position error [m]")
    a1.set_yscale("symlog", linthresh=1.0)
    a2.plot(dist, ohe, "--", color="tab:orange", label="odometry alone")
    a2.plot(dist, he, "-", color="tab:blue", label="fused")
    a2.axhline(1.0, color="k", lw=0.8, ls=":", label="1 deg requirement")
    a2.set_ylabel("heading error [deg]")
    a2.set_xlabel("distance driven [m]")
    for a in (a1, a2):
        a.grid(alpha=0.3)
        a.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, fontsize=8)
    save_figure(fig, path, bbox_inches="tight", dpi=110)
    plt.close(fig)
    return Path(path)


def evaluate_traverse(dem_path, out, *, length_m=3000.0, stop_spacing_m=50.0, seed=0,
                      stop_conditions=None, mode="panorama", map_errors=None, command="") -> Path:
    """Simulate (``OUT/traverse``), fuse (``OUT/result``) and report (``OUT/report.html``); a
    rerun resumes both. Returns the report's path.

    map_errors : render the stops from a world that differs from the map
        (:class:`skyfix.simulate.MapErrors`, as ``simulate-traverse --map-errors``); positions are
        then scored from where the truth's terrain lies on the map (:func:`traverse_errors`)."""
    from ..dem import load_dem
    from ..report import format_table, write_report_html
    from .inputs import read_traverse
    from .measure import acquisition_measure
    from .plots import plot_track
    from .run import convergence_function, run_traverse
    from .simulate import simulate_traverse

    out = Path(out)
    dem = load_dem(dem_path)
    # OUT/traverse is resumed only when simulated with these same options; evaluate's own
    # --overwrite does not reach it, so a refusal offers another -o alone
    simulate_traverse(dem, out / "traverse", length_m=length_m, stop_spacing_m=stop_spacing_m,
                      seed=seed, stop_conditions=stop_conditions, mode=mode,
                      map_errors=map_errors, afresh=None)
    trav = read_traverse(out / "traverse")

    convergence = convergence_function(dem.crs_wkt)
    rows = run_traverse(trav, acquisition_measure(trav, dem), out / "result", convergence=convergence,
                        inputs={"dem_sha256": dem.checksum}, afresh=None)
    dist, pe, he, ope, ohe = traverse_errors(rows, trav, convergence)
    fixes = [k for k, r in enumerate(rows) if r["update"] == "position"]
    upd = [r["update"] for r in rows]
    scripted = sorted((trav.meta.get("simulation") or {}).get("stop_conditions", {}))
    summary = [{
        "stops": len(rows), "length_m": float(dist[-1]), "heading_updates": upd.count("heading"),
        "position_updates": upd.count("position"), "rejected": upd.count("rejected"),
        "none": upd.count("none"),
        "operator_requests": sum(r["operator_request"] is not None for r in rows),
        "heading_within_1deg_pct": 100.0 * float(np.mean(he <= 1.0)),
        "heading_error_max_deg": float(he.max()), "position_error_max_m": float(pe.max()),
        "position_error_end_m": float(pe[-1]), "odometry_alone_end_m": float(ope[-1]),
        "odometry_alone_heading_end_deg": float(ohe[-1])}]
    per_stop = [{"stop": r["stop"], "distance_m": float(d), "update": r["update"],
                 "confidence": r["confidence"] if r["confidence"] is not None else math.nan,
                 "position_error_m": float(p), "heading_error_deg": float(h),
                 "odometry_alone_error_m": float(o),
                 "scripted": "yes" if r["stop"] in scripted else "",
                 "operator_request": "yes" if r["operator_request"] else "",
                 "time_s": r.get("seconds", math.nan)}
                for r, d, p, h, o in zip(rows, dist, pe, he, ope)]
    figs = [plot_track(out / "track.png", rows, trav, dem, convergence),
            plot_errors(out / "errors.png", dist, pe, he, ope, ohe, fixes)]
    if map_errors is None:
        world = "images rendered from the map DEM itself (the map is the world here)"
    else:
        m = map_errors
        world = (f"images rendered from a world that is not the map (--map-errors: {m.refine}x finer, "
                 f"{m.height_rms_m:g} m rms height error, {m.shift_m:g} m misregistration), "
                 "positions scored from where the truth's terrain lies on the map")
    intro = (f"A simulated traverse of {dist[-1]:.0f} m over {Path(dem_path).name}, a stop every "
             f"{stop_spacing_m:g} m (seed {seed}); odometry with 2 % distance and 0.5 deg / 100 m "
             f"heading drift; {world}. "
             f"Scripted conditions at: {', '.join(scripted) or 'none'}.")
    return write_report_html(out, title="skyfix evaluation: traverse", intro=intro,
                             sections=[("Summary", format_table(summary, "html")),
                                       ("Every stop", format_table(per_stop, "html"))],
                             figures=figs, command=command)
