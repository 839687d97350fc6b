"""The position search, :func:`locate`, from a body-frame skyline profile.

Pipeline of :func:`locate`:

1. candidates: the database matcher (:mod:`skyfix.match`) keeps the best K positions in distinct
   basins; without a database (small prior area) a grid is rendered from the DEM over the prior.
2. refinement of every kept candidate (the source study's single-candidate pyramid fell into
   false minima): fresh skylines rendered from the DEM on finer and finer local grids (each level
   4x finer, 9 x 9 points), scored with the same shift search (tilt harmonic removed), made
   robust to gross bins (a near rock) by masking the best point's outlier bins and re-scoring
   (:func:`robust_scores`); a level whose best point is on its edge is re-centred. Candidates
   are ranked by a per-bin clipped cost (:func:`robust_cost`), not the plain rms.
3. attitude: yaw, pitch and roll by Gauss-Newton against the rendered horizon, with restarts at
   -2.5/0/+2.5 deg per axis around the first guess; the query is then re-levelled with the
   estimated attitude and the finest position levels are redone.
4. confidence: a logistic model on features of the score landscape (best vs best of another basin,
   residual vs expected noise, relief of the skyline), fitted on simulated cases by
   ``scripts/calibrate_confidence.py`` (``skyfix/models/confidence.json``).
5. retry (database only): a fix with low confidence or a residual far above the noise is searched
   again with each quarter of the observed skyline left out in turn; the new candidates go
   through 2-3 and the best on the whole profile wins. A false fragment of skyline can outweigh
   the rest of the view in the database's sum of squares; one of the partial searches leaves it
   out.

The forward model (world horizon -> body-frame profile for an attitude) is :func:`body_profile`.
"""

from __future__ import annotations

import logging
import math
from dataclasses import replace

import numpy as np

from ..errors import ParameterError, SkyfixError
from ..match import match_database, observed_span_deg, prepare_query, tilt_determinable
from ..north import heading_360, meridian_convergence_deg, true_heading_deg, wrap_deg
from ..progress import stage
from .basin_sigma import disc_share, rect_share, rival_heading_sigma, wrong_basin_radius
from .confidence import (calibrated_sigma, confidence_features, confidence_from_features,
                         load_confidence_model, position_sigma, residual_correlation_bins,
                         structureless_cap)
from .config import PoseConfig
from .fix import UNKNOWN_HEADING_SIGMA_DEG, Fix, crs_and_lonlat, prior_disagreement
from .image_plane import (IMAGE_PLANE_MAX_SPAN_DEG, SOLVES_DISAGREE_CONFIDENCE,
                          image_plane_attitude, view_span_deg)
from .map_error import fit_map_covariance
from .other_map import map_agreement
from .refine import inside_dem, prior_grid, refine_candidates, same_basin
from .scoring import Renders, clipped_costs, profile_arrays, render_points, robust_scores


log = logging.getLogger(__name__)

#: the most confidence a degenerate search may report (:func:`degenerate_search`)
DEGENERATE_CAP = 0.45
#: [deg] the narrowest view the confidence models were calibrated on (views of 120-360 deg):
#: a narrower one's position confidence is the model extrapolating (one navcam frame, 40-46
#: bins, gave 0.80 on fixes 18-37 m off)
CALIBRATED_MIN_SPAN_DEG = 120.0

#: fewer database positions than this in the searched area is a degenerate search
MIN_SEARCHED_POSITIONS = 49


def degenerate_search(db, dem, x, y, prior_xy, prior_radius_m, tolerance_m, grid_step_m):
    """Why a search cannot support a confident answer, whatever its scores say (a list of
    reasons, empty when none): a handful of positions searched, the answer outside the searched
    area or on its edge (the truth may lie beyond it), or a grid far coarser than the accuracy
    asked with no DEM to refine on. Positions [m].

    The refinement on the DEM (:func:`~skyfix.pose.refine.refine_candidates`) is not held inside
    the searched area: its re-centred grids and its compass search follow the cost wherever the
    DEM has heights, so a rover standing beyond the database's positions or the prior disc is
    found where it stands. Such an answer is kept, not clamped to the edge (a clamped position
    is one the skyline does not support, with a sigma that does not cover its error); it is said
    to lie outside, and how far, since no rival beyond the edge was ever compared with it."""
    reasons = []
    outside = []  # (how far beyond [m], the area, how to search it)
    if db is not None:
        xs, ys = np.asarray(db.x_coords, float), np.asarray(db.y_coords, float)
        n = xs.size * ys.size
        if prior_xy is not None and prior_radius_m is not None:
            # counted a band of rows at a time: the whole grid's coordinates would be 31 MB at
            # the 7 x 7 km database's 1.96 M positions, the board's peak
            n = sum(int(np.count_nonzero(np.hypot(xs[None, :] - prior_xy[0], ys[r:r + 64, None] -
                                                  prior_xy[1]) <= prior_radius_m))
                    for r in range(0, ys.size, 64))
        if n < MIN_SEARCHED_POSITIONS:
            reasons.append(f"only {n} database position{'s' * (n != 1)} searched (fewer than "
                           f"{MIN_SEARCHED_POSITIONS})")
        step = float(db.spacing_m)
        if dem is None and step > 2.0 * tolerance_m:
            reasons.append(f"database grid of {step:g} m against an accuracy of {tolerance_m:g} m, "
                           "with no DEM to refine on")
        lo_x, hi_x, lo_y, hi_y = xs.min(), xs.max(), ys.min(), ys.max()
        edge = min(x - lo_x if xs.size > 1 else np.inf, hi_x - x if xs.size > 1 else np.inf,
                   y - lo_y if ys.size > 1 else np.inf, hi_y - y if ys.size > 1 else np.inf)
        outside.append((math.hypot(max(lo_x - x, 0.0, x - hi_x), max(lo_y - y, 0.0, y - hi_y)),
                        f"the database's positions, x {lo_x:.1f}..{hi_x:.1f} and y "
                        f"{lo_y:.1f}..{hi_y:.1f} m", "a database built over a wider area"))
    else:
        step, edge = float(grid_step_m), np.inf
    if prior_xy is not None and prior_radius_m is not None:
        d = math.hypot(x - prior_xy[0], y - prior_xy[1])
        edge = min(edge, prior_radius_m - d)
        outside.append((d - prior_radius_m, f"the prior disc of {prior_radius_m:g} m around "
                        f"({prior_xy[0]:.1f}, {prior_xy[1]:.1f})", "a wider --prior-radius-m"))
    # beyond every searched position's own half step: no position searched stands for it
    far = max(outside, default=(0.0, "", ""))
    if far[0] > step / 2.0:
        reasons.append(f"the answer lies {far[0]:.1f} m outside the searched area ({far[1]}): "
                       "refinement on the DEM followed the skyline past its edge, and no rival "
                       f"beyond the edge was searched; search an area that holds it ({far[2]})")
    elif edge < step:
        reasons.append(f"the answer lies within one grid step ({step:g} m) of the searched "
                       "area's edge: the rover may be outside it")
    return reasons


def default_camera_height_m(db, profile) -> float:
    """The camera's height [m] above the DEM surface when none is given: the database's, else the
    profile's (``meta['camera_height_m']``), else 1.5."""
    return float(getattr(db, "camera_height_m", None) or profile.meta.get("camera_height_m", 1.5))


def _searched_share(db, prior_xy, prior_radius_m, x, y):
    """``r -> `` the share of the searched area within ``r`` [m] of (x, y): the database's grid
    (each position standing for its cell), inside the prior disc where one was given."""
    disc = None if prior_xy is None or prior_radius_m is None else (*prior_xy, prior_radius_m)
    if db is None:
        return disc_share(*disc, x, y)
    xs, ys = np.asarray(db.x_coords, float), np.asarray(db.y_coords, float)
    h = float(db.spacing_m) / 2.0
    return rect_share(xs.min() - h, xs.max() + h, ys.min() - h, ys.max() + h, x, y, disc=disc)


def _decide(results, rest, q, noise, relief, sep, prior_pitch_deg, prior_roll_deg, model, key,
            one_basin=None):
    """The best refined result, its uncertainties and confidence. results: refined dicts sorted
    by cost; rest: unrefined candidates (x, y, score, heading); sep [m]: how far another answer
    must be to count as a rival; one_basin(best, d): whether refined result d lies in the best
    one's basin all the same (then it is no rival, and ``d["best_basin"]`` says so)."""
    best = results[0]
    far = lambda x, y: math.hypot(x - best["x"], y - best["y"]) > sep  # noqa: E731
    # results are sorted by cost: the first rival is the cheapest, and the rest need no check
    rival = np.inf
    for d in results[1:]:
        if far(d["x"], d["y"]):
            d["best_basin"] = one_basin is not None and one_basin(best, d)
            if not d["best_basin"]:
                rival = d["cost"]
                break
    other = min([rival] + [c[2] for c in rest if far(c[0], c[1])])
    att = best["att"]
    obs = np.isfinite(q)
    corr = residual_correlation_bins(best["resid"])
    psig = position_sigma(best["local"], best["score"], int(obs.sum()), noise, corr_bins=corr)
    tilt = math.hypot(att.pitch_deg - prior_pitch_deg, att.roll_deg - prior_roll_deg)
    feat = confidence_features(best["cost"], other, att.robust_rms_deg, noise, relief,
                               float(obs.mean()), psig, tilt)
    conf = structureless_cap(confidence_from_features(feat, model, key), relief, noise)
    return dict(x=best["x"], y=best["y"], heading=att.yaw_deg, pitch=att.pitch_deg,
                roll=att.roll_deg, cost=best["cost"], psig=calibrated_sigma(psig, feat, model, key),
                # the fit's sigma counts every bin as independent; neighbouring residuals are
                # not (the same correction as the position sigma's)
                hsig=att.yaw_sigma_deg * math.sqrt(max(1.0, corr)),
                feat=feat, conf=conf)


def _floor_check(dem, q, sep, config, *, camera_height_m, planet, prior_pitch_deg, prior_roll_deg,
                 noise):
    """``one_basin(best, d)`` for :func:`_decide`: whether refined result d lies on the best one's
    floor of the attitude-refitted cost (:func:`~skyfix.pose.refine.same_basin`, sampled every
    ``sep / 2`` [m]), said in the log when it does."""
    renders = Renders(dem, camera_height_m=camera_height_m, planet=planet)

    def one_basin(a, d):
        same = same_basin(renders, q, (a["x"], a["y"], a["cost"]), (d["x"], d["y"], d["cost"]),
                          a["att"], spacing_m=sep / 2.0, render_bins=config.render_bins,
                          prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg,
                          noise=noise, dem_sigma_m=config.dem_sigma_m)
        if same:
            log.info("(%.1f, %.1f) lies in the best answer's basin (no ridge of cost between "
                     "them): not a rival", d["x"], d["y"])
        return same
    return one_basin


def _with_map_share(psig, hsig, feat, dem, q, out, noise, config, camera_height_m, planet,
                    prior_pitch_deg, prior_roll_deg):
    """The position sigma [m] and heading sigma [deg] widened by what the map's height error
    (``config.map_sigma_m``; 0: the DEM is the world) does to the fit
    (:func:`~skyfix.pose.map_error.fit_map_covariance`), added in quadrature. The fitted sigmas
    (the score surface's curvature and the attitude fit's, calibrated) see the residual, not a
    map that pulls the answer while fitting well. Both parts go into ``feat``
    (``position_sigma_fit_m``, ``position_sigma_map_m``, ``heading_sigma_map_deg``)."""
    from ..horizon import render_horizons

    dem_sigma = float(config.map_sigma_m)
    feat["position_sigma_fit_m"] = float(psig)
    if dem_sigma <= 0:
        return psig, hsig

    def world_at(xs, ys):
        ok = inside_dem(dem, xs, ys, 0.0)
        el = np.full((xs.size, config.render_bins), np.nan, np.float32)
        dist = np.full_like(el, np.nan)
        if ok.any():
            hb = render_horizons(dem, xs[ok], ys[ok], camera_height_m=camera_height_m,
                                 planet=planet, azimuth_bins=config.render_bins)
            el[ok], dist[ok] = hb.elevation_deg, hb.skyline_distance_m
        return el, dist

    cov = fit_map_covariance(q, world_at, out["x"], out["y"], out["heading"], out["pitch"],
                             out["roll"], noise_deg=noise, dem_sigma_m=dem_sigma,
                             prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg)
    if cov is None:  # too few bins to say: the fitted sigmas stand
        return psig, hsig
    var = np.diag(cov)
    if not (np.all(np.isfinite(var[:3])) and np.all(var[:3] >= 0)):  # a singular fit
        return psig, hsig
    sd_pos, sd_yaw = math.sqrt(var[0] + var[1]), math.sqrt(var[2])
    feat["position_sigma_map_m"] = sd_pos
    feat["heading_sigma_map_deg"] = sd_yaw
    return float(math.hypot(psig, sd_pos)), float(math.hypot(hsig, sd_yaw))


def _segment_candidates(db, q, config, known, *, prior_xy=None, prior_radius_m=None):
    """Database candidates (x, y, score, heading) found with each of ``config.retry_segments``
    contiguous parts of the observed skyline left out in turn, farther than the tolerance from
    every position in ``known`` and from each other (the first ``retry_per_segment`` of each
    search)."""
    obs = np.flatnonzero(np.isfinite(q))
    out = []
    for part in np.array_split(obs, max(1, config.retry_segments)):
        if part.size == 0 or obs.size - part.size < config.match.min_observed:
            continue
        qk = q.copy()
        qk[part] = np.nan
        m = match_database(db, qk, config.match, prior_xy=prior_xy, prior_radius_m=prior_radius_m)
        for c in m.candidates[: config.retry_per_segment]:
            if all(math.hypot(c.x - x, c.y - y) > config.tolerance_m for x, y in known):
                out.append((c.x, c.y, c.score, c.heading_deg))
                known = known + [(c.x, c.y)]
    return out


def _log_candidates(where, cands):
    """-v: the candidates a search kept (x [m], y [m], score, heading [deg]), best first."""
    log.info("%s: %d candidate%s kept%s", where, len(cands), "s" * (len(cands) != 1),
             ": " + "; ".join(f"({x:.1f}, {y:.1f}) score {s:.4g} heading {h:.1f}"
                              for x, y, s, h in cands[:8]) if cands else "")


def _log_refined(results):
    """-v: where each refined candidate went from where it started, and its cost."""
    for d in results:
        x0, y0 = d["start"]
        log.info("refined (%.1f, %.1f) -> (%.1f, %.1f), moved %.1f m: clipped cost %.4f deg^2, "
                 "heading %.2f deg", x0, y0, d["x"], d["y"], math.hypot(d["x"] - x0, d["y"] - y0),
                 d["cost"], d["heading"])


def locate(profile, *, db=None, dem=None, prior_xy=None, prior_radius_m=None,
           prior_pitch_deg: float = 0.0, prior_roll_deg: float = 0.0,
           camera_height_m: float | None = None, planet=None, config: PoseConfig = PoseConfig(),
           model: dict | None = None, return_match: bool = False, notes: tuple = (),
           frames=None):
    """Position, heading and attitude from a body-frame profile.

    profile : :class:`skyfix.formats.Profile` (frame ``body``, levelled with the attitude prior)
    db : an opened skyline database (or anything with its read API); None for a small prior area
    dem : the DEM the database was built from; needed to refine (and without a database)
    prior_xy, prior_radius_m : [m] search disc (required without a database)
    prior_pitch_deg, prior_roll_deg : [deg] the attitude prior the profile was levelled with
    camera_height_m : [m] the camera above the DEM surface (default: the database's, else the
        profile's, else 1.5); refinement renders at it. When it differs from the database's, the
        database search compared skylines seen from another height: the position sigma is widened
        by the difference (added in quadrature) and a note says so
    notes : what the caller already knows the fix should say (a forced DEM, ...)
    frames : the frames' detected rows (:class:`~skyfix.pose.image_plane.FrameRows`): with a DEM,
        a view spanning at most ``IMAGE_PLANE_MAX_SPAN_DEG`` gets its heading, pitch and roll
        solved again in the image plane at the fix (as :func:`estimate_heading` does)
    Returns a :class:`Fix` (and the :class:`skyfix.match.MatchResult` with ``return_match``).
    """
    if getattr(profile, "frame", "body") not in ("body", None):
        raise ParameterError(f"locate needs a body-frame profile, got frame '{profile.frame}'")
    q, noise = profile_arrays(profile)
    n = q.size
    if db is None and dem is None:
        raise ParameterError("locate needs a skyline database (--db) or a DEM with a prior area")
    if db is None and (prior_xy is None or prior_radius_m is None):
        raise ParameterError("without a database, give a prior position and radius "
                             "(--prior-x, --prior-y, --prior-radius-m) and a DEM")
    if prior_xy is not None and not all(math.isfinite(float(v)) for v in prior_xy):
        raise ParameterError(f"prior position must be finite [m], got {tuple(prior_xy)}")
    if prior_radius_m is not None and not (math.isfinite(prior_radius_m) and prior_radius_m > 0):
        raise ParameterError(f"prior radius must be a finite number of metres > 0, got {prior_radius_m}")
    if model is None:  # read once: the confidence and the sigma both use it
        model = load_confidence_model()
    if camera_height_m is None:
        camera_height_m = default_camera_height_m(db, profile)
    camera_height_m = float(camera_height_m)
    db_height = float(getattr(db, "camera_height_m", camera_height_m) or camera_height_m)
    height_gap = abs(camera_height_m - db_height) if db is not None else 0.0
    if planet is None and db is not None:  # the database's (its DEM's body); else the DEM's own
        planet = getattr(db, "planet", None) or "earth"
        if isinstance(planet, dict):
            planet = planet.get("name") or planet.get("radius_m") or "earth"
    notes = list(notes)
    if config.match.remove_tilt and not tilt_determinable(np.isfinite(q)):
        # A single frame or a partial view spans too narrow an arc to tell a tilt from a
        # constant and a heading shift: the search trusts the attitude prior instead (the
        # refinement still fits pitch and roll); refusing such a view helped nobody.
        config = replace(config, match=replace(config.match, remove_tilt=False))
        notes.append("the observed skyline spans too narrow an arc to separate a tilt: the "
                     "search took the attitude prior as the tilt")
    mres = None
    if db is not None:
        with stage("  database searched") as st:
            mres = match_database(db, q, config.match, prior_xy=prior_xy,
                                  prior_radius_m=prior_radius_m)
            k = len(mres.candidates)
            st.result = f"{k} candidate{'s' * (k != 1)}"
        cands = [(c.x, c.y, c.score, c.heading_deg) for c in mres.candidates]
        _log_candidates("database search", cands)
        step0 = float(db.spacing_m) / 4.0
        crs_wkt = getattr(db, "crs_wkt", "") or (dem.crs_wkt if dem is not None else "")
    else:
        step = config.grid_step_m
        gx, gy = prior_grid(dem, prior_xy, float(prior_radius_m), step)
        ok = inside_dem(dem, gx, gy, 0.0)
        if not ok.any():
            raise ParameterError("the prior area lies outside the DEM")
        gx, gy = gx[ok], gy[ok]
        prepare_query(q, config.match.remove_tilt, config.match.min_observed)  # validates the view
        pts = render_points(dem, gx, gy, camera_height_m=camera_height_m, planet=planet, n_bins=n)
        _, sh, _ = robust_scores(pts, q, remove_tilt=config.match.remove_tilt)
        # Candidates by the clipped cost: rocks covering a quarter of the view (OCCL) named the
        # wrong outlier bins at the sum-of-squares optimum and kept the true basin out of the
        # refined few; clipped, each rock bin costs the same everywhere.
        sc = clipped_costs(pts, q, sh, config.match.remove_tilt)
        order = np.argsort(sc)
        cands = []
        for i in order:
            if all(math.hypot(gx[i] - c[0], gy[i] - c[1]) > 2.5 * step for c in cands):
                cands.append((float(gx[i]), float(gy[i]), float(sc[i]), float(sh[i]) * 360.0 / n))
            if len(cands) >= config.match.top_k:
                break
        _log_candidates(f"prior area, {gx.size} points at {step:g} m on the DEM,", cands)
        step0 = step / 4.0
        crs_wkt = dem.crs_wkt
    if not cands:
        raise SkyfixError("no candidate position found: the database holds no usable skyline")
    relief = float(np.nanstd(q))
    # "Another basin" is another answer beyond the tolerance. Without a database the answer is
    # judged at scenario 2's tolerance (1 m), not 5 m.
    sep = config.tolerance_m if db is not None else 1.0
    if dem is not None:
        kw = dict(camera_height_m=camera_height_m, planet=planet, prior_pitch_deg=prior_pitch_deg,
                  prior_roll_deg=prior_roll_deg, noise=noise)
        # Refined candidates often converge onto the best one, and comparing with a copy of
        # itself said nothing.
        kw["join_m"] = sep
        k = min(len(cands), config.refine_candidates)
        with stage(f"  {k} candidate{'s' * (k != 1)} refined on the DEM") as st:
            results = refine_candidates(dem, q, cands[: config.refine_candidates], step0, config, **kw)
            st.result = f"best clipped cost {results[0]['cost']:.4f} deg^2" if results else "none"
        _log_refined(results)
        rest = list(cands[config.refine_candidates:])
        # Scenario 2 counts answers 1 m apart as rivals, and one flat valley can be wider: starts
        # that stopped 1.1 m from the best on its floor made the confidence turn on the prior's
        # last decimals (0.80 against 0.49 for priors 1 cm apart). A database's 5 m is wider
        # than such floors (and its calibration cases were not rerun with the check).
        one_basin = None if db is not None else _floor_check(
            dem, q, sep, config, camera_height_m=camera_height_m, planet=planet,
            prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg, noise=noise)
        out = _decide(results, rest, q, noise, relief, sep, prior_pitch_deg, prior_roll_deg,
                      model, "locate" if db is not None else "locate_prior", one_basin)
        if db is not None and (out["conf"] < config.retry_below or
                               out["feat"]["log_rms_over_noise"] > math.log(config.retry_rms_ratio)):
            known = [(d["x"], d["y"]) for d in results] + [(c[0], c[1]) for c in rest]
            extra = _segment_candidates(db, q, config, known, prior_xy=prior_xy,
                                        prior_radius_m=prior_radius_m)
            log.info("confidence %.2f, robust rms %.1f x the noise: searched again with each of "
                     "%d parts of the skyline left out, %d new candidate%s", out["conf"],
                     math.exp(out["feat"]["log_rms_over_noise"]), config.retry_segments,
                     len(extra), "s" * (len(extra) != 1))
            if extra:
                more = refine_candidates(dem, q, extra, step0, config, **kw)
                _log_refined(more)
                results = sorted(results + more, key=lambda d: d["cost"])
                out = _decide(results, rest, q, noise, relief, sep, prior_pitch_deg,
                              prior_roll_deg, model, "locate")
        fx, fy, heading, pitch, roll = out["x"], out["y"], out["heading"], out["pitch"], out["roll"]
        best_s, psig, hsig, feat, conf = out["cost"], out["psig"], out["hsig"], out["feat"], out["conf"]
        psig, hsig = _with_map_share(psig, hsig, feat, dem, q, out, noise, config,
                                     camera_height_m, planet, prior_pitch_deg, prior_roll_deg)
        # a start that stopped on the best answer's floor is that answer, not another candidate
        cand_out = [{"x": d["x"], "y": d["y"], "heading_deg": d["heading"],
                     "score": d["cost"]} for d in results if not d.get("best_basin")]
        # one unit: an unrefined database candidate's score was the search's unclipped mean of
        # squares (3.0 for a clipped 0.17 deg^2): the clipped cost of its stored skyline
        rs = [c[2] for c in rest] if db is None or not rest else clipped_costs(
            db.profiles_at([c[0] for c in rest], [c[1] for c in rest]), q,
            [c[3] * n / 360.0 for c in rest], config.match.remove_tilt)
        cand_out += [{"x": c[0], "y": c[1], "heading_deg": c[3], "score": float(v)} for c, v in
                     zip(rest, rs)]
        # refined onto one answer, one candidate (a fix's own position was listed 3 times)
        kept = []
        for c in cand_out:
            if all(math.hypot(c["x"] - o["x"], c["y"] - o["y"]) > sep for o in kept):
                kept.append(c)
        cand_out = kept
    else:
        cx, cy, cs, ch = cands[0]
        other = cands[1][2] if len(cands) > 1 else np.inf
        best_s = cs
        fx, fy, heading, pitch, roll = cx, cy, ch, prior_pitch_deg, prior_roll_deg
        psig = float(db.spacing_m) / math.sqrt(6)
        hsig, rms = 360.0 / n, math.sqrt(cs)
        tilt = 0.0
        cand_out = [{"x": c[0], "y": c[1], "heading_deg": c[3], "score": c[2]} for c in cands]
        feat = confidence_features(best_s, other, rms, noise, relief, float(np.isfinite(q).mean()),
                                   psig, tilt)
        conf = structureless_cap(confidence_from_features(feat, model, "locate"), relief, noise)
        psig = calibrated_sigma(psig, feat, model, "locate")
    if frames and dem is not None and view_span_deg(frames) <= IMAGE_PLANE_MAX_SPAN_DEG:
        img = image_plane_attitude(frames, dem, fx, fy, heading, pitch, roll,
                                   camera_height_m=camera_height_m, planet=planet,
                                   dem_sigma_m=config.map_sigma_m)
        if img is not None:
            log.info("image-plane solve: yaw %.2f (%+.2f from the profile fit), pitch %.2f, "
                     "roll %.2f deg", img.yaw_deg, wrap_deg(img.yaw_deg - heading), img.pitch_deg,
                     img.roll_deg)
            if abs(wrap_deg(img.yaw_deg - heading)) > 1.0:
                conf = min(conf, SOLVES_DISAGREE_CONFIDENCE)
                notes.append("the image-plane heading lies more than 1 deg from the profile fit's: "
                             f"confidence at most {SOLVES_DISAGREE_CONFIDENCE}")
            heading, pitch, roll = img.yaw_deg, img.pitch_deg, img.roll_deg
            hsig = max(hsig, img.yaw_sigma_deg)
    log.info("fix (%.1f, %.1f), grid heading %.2f, pitch %.2f, roll %.2f deg; clipped cost %.4f "
             "deg^2; confidence %.2f before caps", fx, fy, heading, pitch, roll, best_s, conf)
    log.debug("confidence features: %s", ", ".join(f"{k} {v:.3g}" for k, v in feat.items()))
    # what the confidence says of the basin: the caps below speak of the searched area (the
    # rover may lie outside it), not of another basin inside it
    basin_conf = conf
    degenerate = degenerate_search(db, dem, fx, fy, prior_xy, prior_radius_m, sep,
                                   config.grid_step_m)
    other, same = map_agreement(db, dem, fx, fy)
    degenerate += [other] if other else []
    notes += [same] if same else []
    span = observed_span_deg(q)
    if span < CALIBRATED_MIN_SPAN_DEG:
        degenerate.append(f"the observed skyline spans {span:.0f} deg, narrower than the "
                          f"{CALIBRATED_MIN_SPAN_DEG:g} deg the confidence was calibrated on: a "
                          "narrow view pins the position loosely, and its sigmas may not cover it")
    if degenerate:
        conf = min(conf, DEGENERATE_CAP)
        notes += [f"confidence capped at {DEGENERATE_CAP}: {r}" for r in degenerate]
        for r in degenerate:
            log.info("confidence capped at %s: %s", DEGENERATE_CAP, r)
    if height_gap > 0:
        psig = math.hypot(psig, height_gap)
    # the sigma so far is the basin's own; the confidence says how likely that basin is
    basin = psig
    feat["position_sigma_basin_m"] = basin  # for a filter that settles the basin by its track
    psig = wrong_basin_radius(psig, basin_conf,
                              _searched_share(db, prior_xy, prior_radius_m, fx, fy))
    if psig > 2.0 * basin:
        notes.append(f"the position may lie in another basin of the searched area (a chance of "
                     f"{1.0 - basin_conf:.2f}), and position_sigma_m allows for that (the fit's "
                     f"own is {basin:.2f} m; the candidates list the rivals)")
    # the heading as the position: the basin's own sigma, then the rivals' headings by their chance
    feat["heading_sigma_basin_deg"] = hsig
    rivals = [wrap_deg(c["heading_deg"] - heading) for c in cand_out
              if math.hypot(c["x"] - fx, c["y"] - fy) > sep]
    basin_h, hsig = hsig, rival_heading_sigma(hsig, basin_conf, rivals)
    if hsig > 2.0 * basin_h:
        notes.append(f"the rival basins face other ways (a chance of {1.0 - basin_conf:.2f}), "
                     f"and heading_sigma_deg allows for that (the fit's own is {basin_h:.2f} deg)")
    notes += prior_disagreement(pitch, roll, prior_pitch_deg, prior_roll_deg)
    if dem is None:
        notes.append("pitch_deg and roll_deg are the attitude prior echoed (no --dem to estimate "
                     "them); heading and position come from the database grid")
    crs, lon, lat = crs_and_lonlat(crs_wkt, fx, fy)
    conv = meridian_convergence_deg(crs_wkt, fx, fy)
    for c in cand_out:  # candidates are read like the fix: headings from true north
        c["heading_deg"] = true_heading_deg(float(c["heading_deg"]),
                                            meridian_convergence_deg(crs_wkt, c["x"], c["y"]))
    grid = heading_360(heading)
    fix = Fix(x=float(fx), y=float(fy), crs=crs, lon=lon, lat=lat,
              heading_deg=true_heading_deg(grid, conv), grid_heading_deg=grid,
              meridian_convergence_deg=conv, pitch_deg=float(pitch), roll_deg=float(roll),
              position_sigma_m=float(psig),
              heading_sigma_deg=float(min(hsig, UNKNOWN_HEADING_SIGMA_DEG)), confidence=conf,
              score=float(best_s), candidates=tuple(cand_out), features=feat, notes=tuple(notes))
    return (fix, mres) if return_match else fix
