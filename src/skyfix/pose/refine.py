"""Refinement of candidate positions from the DEM: fresh skylines on finer and finer local grids
(each level 4x finer, 5 x 5 points), a level whose best point is on its edge re-centred, then
the attitude fit and a polish of the position on the attitude-refitted cost.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import ParameterError, SkyfixError
from .attitude import fit_attitude
from .config import MAX_PRIOR_GRID_POINTS
from .forward import body_profile, harmonic_tilt, relevel, residual_profile
from .scoring import Renders, body_distances, robust_cost, score_points


def prior_grid(dem, prior_xy, radius_m, step_m):
    """Grid points [m] at ``step_m`` over the prior square (centre ``prior_xy``, half-side
    ``radius_m``), only the part on the DEM: a radius reaching past the DEM costs nothing.
    Raises ParameterError when the area lies off the DEM or needs more than
    MAX_PRIOR_GRID_POINTS renders."""
    xmin, ymin, xmax, ymax = dem.bounds
    px, py = float(prior_xy[0]), float(prior_xy[1])
    k = math.ceil(radius_m / step_m)
    i0, i1 = max(-k, math.ceil((xmin - px) / step_m)), min(k, math.floor((xmax - px) / step_m))
    j0, j1 = max(-k, math.ceil((ymin - py) / step_m)), min(k, math.floor((ymax - py) / step_m))
    if i0 > i1 or j0 > j1:
        raise ParameterError("the prior area lies outside the DEM")
    n = (i1 - i0 + 1) * (j1 - j0 + 1)
    if n > MAX_PRIOR_GRID_POINTS:
        r_max = (math.isqrt(MAX_PRIOR_GRID_POINTS) // 2) * step_m
        raise ParameterError(
            f"without a database the search renders a skyline every {step_m:g} m over the prior "
            f"area: a {radius_m:g} m radius is {n:,} points on the DEM (at most "
            f"{MAX_PRIOR_GRID_POINTS:,}, a radius of about {r_max:g} m); give a smaller "
            "--prior-radius-m, or build a database over the area (skyfix build-db) and pass --db")
    gx, gy = np.meshgrid(px + np.arange(i0, i1 + 1) * step_m, py + np.arange(j0, j1 + 1) * step_m)
    return gx.ravel(), gy.ravel()


def inside_dem(dem, xs, ys, margin):
    """Bool per point (xs, ys) [m]: at least ``margin`` [m] inside the DEM and on a known height."""
    return np.asarray(dem.contains(xs, ys, margin), bool) & np.isfinite(dem.height_at(xs, ys))


def refine_grid(dem, q, x, y, step, levels, *, camera_height_m, planet, remove_tilt,
                max_moves=3, renders=None, half=2):
    """Local grid search around (x, y) [m], each level 4x finer than the one before.

    Each level spans +/- ``half`` steps (5 x 5 points): the level before placed the best point
    within half its step, two of these. When the best point lies on a grid's edge the level is
    re-centred there and redone (at most ``max_moves`` times in all): with 10 deg of pitch/roll
    the database's candidate can sit 10-15 m from the true basin. The finest level ends centred
    on its best point, so ``local`` holds its whole neighbourhood for the position sigma
    (:func:`~skyfix.pose.confidence.position_sigma`). 9 x 9 grids (``half=4``), as before
    2026-11-26, rendered twice the points for the same fixes (40 scenario-1 cases: the same
    tallies and calibration, docs/board-memory.md).
    Returns (x, y, score, heading_deg, local) with ``local`` (xs, ys, scores, step) of the
    finest level."""
    n = q.size

    def level_at(x, y, step):
        off = np.arange(-half, half + 1) * step
        gx, gy = np.meshgrid(x + off, y + off)
        gx, gy = gx.ravel(), gy.ravel()
        ok = inside_dem(dem, gx, gy, 0.0)
        if not ok.any():
            return None
        gx, gy = gx[ok], gy[ok]
        sc, sh = score_points(dem, gx, gy, q, camera_height_m=camera_height_m, planet=planet,
                              n_bins=n, remove_tilt=remove_tilt, renders=renders)
        i = int(np.argmin(sc))
        return gx, gy, sc, sh, i

    best = local = None
    moves = 0
    for _ in range(levels):
        while True:
            r = level_at(x, y, step)
            if r is None:
                break
            gx, gy, sc, sh, i = r
            on_edge = max(abs(gx[i] - x), abs(gy[i] - y)) > (half - 0.5) * step
            x, y = float(gx[i]), float(gy[i])
            best = (x, y, float(sc[i]), float(sh[i]) * 360.0 / n)
            local = (gx, gy, sc, step)
            if not on_edge or moves >= max_moves:
                break
            moves += 1
        if best is None:
            break
        step /= 4.0
    if best is None:
        raise SkyfixError(f"no refinement point near ({x:.1f}, {y:.1f}) lies inside the DEM")
    gx, gy, sc, fine = local
    if gx.size == (2 * half + 1) ** 2 and x == gx[gx.size // 2] and y == gy[gy.size // 2]:
        return (*best, local)
    # The best point is off the finest grid's centre: the grid around it for the sigma (most of
    # its points are rendered already).
    gx, gy, sc, sh, i = level_at(x, y, fine)
    return float(gx[i]), float(gy[i]), float(sc[i]), float(sh[i]) * 360.0 / n, (gx, gy, sc, fine)


def refine_candidate(dem, q, cx, cy, ch, step0, config, *, camera_height_m, planet,
                      prior_pitch_deg, prior_roll_deg, noise):
    """Attitude, then position, then attitude again around one candidate (x, y [m], heading [deg]).

    The attitude comes first: with 10 deg of pitch/roll the tilt-harmonic removal of the shift
    search is only approximate and biased the fine position by 5-15 m; levelling the query with
    the attitude fitted at the candidate (far horizon: insensitive to metres) removes that bias.
    Returns (x, y, score, local, attitude, clipped cost, residual profile [deg])."""
    n = q.size

    renders = Renders(dem, camera_height_m=camera_height_m, planet=planet)

    def world_at(x, y):
        return renders.horizons([x], [y], config.render_bins)[0][0]

    def fit(world, yaw0, p0, r0, restarts):
        return fit_attitude(q, world, yaw0, p0, r0, restarts_deg=restarts,
                            prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg,
                            accept_deg=2.0 * max(noise, 0.05))

    def level(att):
        if max(abs(att.pitch_deg - prior_pitch_deg), abs(att.roll_deg - prior_roll_deg)) < 0.3:
            return q
        ql = relevel(q, att.pitch_deg, att.roll_deg, prior_pitch_deg=prior_pitch_deg,
                     prior_roll_deg=prior_roll_deg)
        return ql if np.isfinite(ql).sum() >= 20 else q

    kw = dict(camera_height_m=camera_height_m, planet=planet,
              remove_tilt=config.match.remove_tilt, renders=renders)
    world = world_at(cx, cy)
    p0, r0 = harmonic_tilt(q, body_profile(world, ch, n_bins=n))
    att = fit(world, ch, prior_pitch_deg + p0, prior_roll_deg + r0, config.restarts_deg)
    x, y, s, hd, local = refine_grid(dem, level(att), cx, cy, step0, config.levels, **kw)
    world = world_at(x, y)
    att = fit(world, att.yaw_deg, att.pitch_deg, att.roll_deg, (0.0,))
    ql = level(att)
    if ql is not q and config.levels > 1:
        # The attitude moved with the position: redo the finest level with the new levelling.
        fine = step0 / 4.0 ** (config.levels - 1)
        x, y, s, hd, local = refine_grid(dem, ql, x, y, fine, 1, **kw)
        world = world_at(x, y)
        att = fit(world, att.yaw_deg, att.pitch_deg, att.roll_deg, (0.0,))
    resid = residual_profile(q, world, att, prior_pitch_deg=prior_pitch_deg,
                             prior_roll_deg=prior_roll_deg)
    return x, y, s, local, att, robust_cost(resid, noise), resid


def refit_costs(renders, q, xs, ys, att, *, render_bins, prior_pitch_deg, prior_roll_deg, noise,
                dem_sigma_m=None):
    """The attitude-refitted cost at each position (xs, ys) [m]: a horizon rendered there
    (``renders``, a :class:`~skyfix.pose.scoring.Renders`), yaw, pitch and roll fitted to it from
    ``att`` (one Gauss-Newton start), and :func:`robust_cost` [deg^2] of the residual. Returns a
    (cost, attitude, residual profile [deg]) per position; (inf, None, None) off the DEM."""
    kw = dict(prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg)
    xs, ys = np.atleast_1d(np.asarray(xs, float)), np.atleast_1d(np.asarray(ys, float))
    ok = inside_dem(renders.dem, xs, ys, 0.0)
    out = [(np.inf, None, None)] * xs.size
    if ok.any():
        els, dists = renders.horizons(xs[ok], ys[ok], render_bins)
        for i, wi, di in zip(np.flatnonzero(ok), els, dists):
            a = fit_attitude(q, wi, att.yaw_deg, att.pitch_deg, att.roll_deg, restarts_deg=(0.0,),
                             **kw)
            r = residual_profile(q, wi, a, **kw)
            dist = body_distances(di, a.yaw_deg, q.size) if dem_sigma_m else None
            out[i] = (robust_cost(r, noise, dist, dem_sigma_m), a, r)
    return out


def same_basin(renders, q, a, b, att, *, spacing_m, max_points=8, rise=0.01, **fit):
    """Whether two refined answers a and b, each (x [m], y [m], cost [deg^2]), lie in one basin
    of the attitude-refitted cost: no point on the segment between them (sampled at most
    ``spacing_m`` [m] apart) costs more than ``1 + rise`` times the dearer end. Starts that
    stop at different places on one flat floor (the polish stops where a step gains under 0.1 %)
    are not rival answers; a ridge of cost between them is what makes two basins. A segment
    needing more than ``max_points`` samples is not examined (False: a rival, as before).
    ``att``: the attitude the fits start from; ``fit``: :func:`refit_costs`'s keywords."""
    (xa, ya, ca), (xb, yb, cb) = a, b
    k = math.ceil(math.hypot(xb - xa, yb - ya) / spacing_m)
    if k > max_points + 1:
        return False
    if k < 2:
        return True
    t = np.arange(1, k) / k
    costs = [c for c, _, _ in refit_costs(renders, q, xa + t * (xb - xa), ya + t * (yb - ya), att,
                                          **fit)]
    return bool(max(costs) <= max(ca, cb) * (1.0 + rise))


def polish_position(dem, q, x, y, att, *, camera_height_m, planet, render_bins, prior_pitch_deg,
                     prior_roll_deg, noise, step_m=0.5, min_step_m=0.03, max_evals=120,
                     min_gain=1e-3, dem_sigma_m=None, basins=(), join_m=None):
    """Compass search of the position [m] on the attitude-refitted cost (:func:`robust_cost`).

    The grid refinement (:func:`refine_grid`) ranks points by the shift search's score: whole-bin
    azimuth shifts of a query levelled with an attitude fitted elsewhere. With 10 deg of tilt its
    noise floor (~0.03 deg rms) hides metre-scale position information (a fix 1.3 m off whose
    own cost was three times the truth's). Here every trial point gets its own yaw, pitch and
    roll (Gauss-Newton from the current attitude, ~10 ms), so the cost is the model's own.
    The 8 neighbours at the current step (``step_m`` at first) are tried; the best is taken when
    it lowers the cost by more than ``min_gain`` of it, and the step doubles (up to 8
    ``step_m``), else the step halves, down to ``min_step_m``. After a move, the same direction
    at the doubled step is tried alone first and taken if it gains (a pattern move): walks of
    10-20 m from a tilt-biased grid point used up ``max_evals`` at eight fits a stride and
    stopped short of the floor (a scenario-2 case 0.35 m off instead of 0.14). Without the
    margin a wrong basin's flat floor kept the search stepping by 0.05 % gains until
    ``max_evals`` (three of a fix's four candidates, 121 fits each): differences a thousand
    times below what the cost's own sampling noise can tell apart.
    ``dem_sigma_m`` [m]: weigh bins by the DEM's trust there (:func:`robust_cost`).
    ``basins``: (x [m], y [m], cost) of candidates polished already; a search that comes within
    ``join_m`` [m] of one whose cost is no higher than its own stops there: it has walked into
    a known answer's basin (two of a fix's four candidates walked 22 m to the best one, 125
    fits each) and would only find that answer again.
    Returns (x, y, attitude, cost, residual profile [deg]).
    """
    renders = Renders(dem, camera_height_m=camera_height_m, planet=planet)

    def evaluate(xs, ys, a0):
        return refit_costs(renders, q, xs, ys, a0, render_bins=render_bins,
                           prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg,
                           noise=noise, dem_sigma_m=dem_sigma_m)

    (cost, att, resid), = evaluate([x], [y], att)
    if att is None:
        raise SkyfixError(f"the position ({x:.1f}, {y:.1f}) lies outside the DEM")
    ring = np.array([(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1) if (i, j) != (0, 0)], float)

    def joined():
        return join_m is not None and any(
            c <= cost and math.hypot(x - bx, y - by) <= join_m for bx, by, c in basins)

    def gains(trial):
        return trial[0] < cost * (1.0 - min_gain)

    step, evals, last = float(step_m), 1, None
    while step >= min_step_m and evals < max_evals and not joined():
        trials = {}
        if last is not None:
            # The direction that has just paid, at the new step, before the others: a walk of
            # metres then costs one fit a stride instead of eight.
            trials[last], = evaluate([x + step * ring[last, 0]], [y + step * ring[last, 1]], att)
            evals += 1
        if last is None or not gains(trials[last]):
            rest = [i for i in range(len(ring)) if i not in trials]
            trials.update(zip(rest, evaluate(x + step * ring[rest, 0], y + step * ring[rest, 1],
                                             att)))
            evals += len(rest)
        k = min(trials, key=lambda i: (trials[i][0], i))
        if gains(trials[k]):
            x, y = x + step * ring[k, 0], y + step * ring[k, 1]
            cost, att, resid = trials[k]
            step = min(2.0 * step, 8.0 * step_m)  # a long way to go: stride out
            last = k
        else:
            step /= 2.0
            last = None
    return float(x), float(y), att, float(cost), resid


def refine_candidates(dem, q, cands, step0, config, *, camera_height_m, planet, prior_pitch_deg,
             prior_roll_deg, noise, join_m=None):
    """Refine (:func:`refine_candidate`) and polish (:func:`polish_position`) each candidate
    (x [m], y [m], score, heading [deg]); result dicts sorted by the clipped cost. The polish
    goes from the lowest refined cost up, and a candidate's stops in the basin of one polished
    before it (``join_m`` [m]: within that distance, the answer counted as the same)."""
    results = []
    for cx, cy, cs, ch in cands:
        x, y, s, local, att, cost, resid = refine_candidate(
            dem, q, cx, cy, ch, step0, config, camera_height_m=camera_height_m, planet=planet,
            prior_pitch_deg=prior_pitch_deg, prior_roll_deg=prior_roll_deg, noise=noise)
        # start: where the candidate was before refinement, to say how far it walked
        results.append(dict(x=x, y=y, score=s, heading=att.yaw_deg, att=att, local=local,
                            db_score=cs, cost=cost, resid=resid, start=(float(cx), float(cy))))
    if config.polish:
        # Every refined candidate gets the same final polish: the grid's score can leave the
        # true basin's candidate behind a worse one (rocks over a quarter of the view), and the
        # confidence's best-vs-other ratio then compares like with like.
        basins = []
        for d in sorted(results, key=lambda d: d["cost"]):
            x, y, att_p, cost_p, resid_p = polish_position(
                dem, q, d["x"], d["y"], d["att"], camera_height_m=camera_height_m, planet=planet,
                render_bins=config.render_bins, prior_pitch_deg=prior_pitch_deg,
                prior_roll_deg=prior_roll_deg, noise=noise, dem_sigma_m=config.dem_sigma_m,
                basins=basins, join_m=join_m)
            d.update(x=x, y=y, att=att_p, heading=att_p.yaw_deg, cost=cost_p, resid=resid_p)
            basins.append((x, y, cost_p))
    # Ranked by the clipped cost: plain rms let outlier bins pick the wrong basin.
    results.sort(key=lambda d: d["cost"])
    return results
