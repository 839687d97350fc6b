"""The traverse loop: odometry between stops, a skyline heading at every stop, a skyline position
fix at the end of each leg, gated, retried, and an operator request instead of a crash.

Per stop (the rover's activity diagram in the source study):

1. predict with the odometry from the previous stop;
2. decide the update: a position fix (``locate`` in a disc of 3 sigma about the prediction) at the
   end of a leg (``leg_length_m`` driven since the last accepted fix, to within 3 %; the
   traverse's last stop ends the last leg), when the position sigma has
   grown past what the heading mode tolerates (``max_position_sigma_m``), or while an earlier
   fix is still owed; else a heading (``heading`` at the predicted position in a window of
   ``max(heading_window_deg, 3 sigma)`` about the predicted heading);
3. measure; a measurement below ``min_confidence`` is retried once (a heading with the window
   doubled; a fix with the disc doubled); an error (no skyline detected, too few bins) is a
   failed detection;
4. gate: the innovation's chi-square at 99.9 % against the filter's and the measurement's
   covariance together; outside it, rejected (a confident-looking outlier). A measurement still
   below ``min_confidence`` after the retry is taken only when the track corroborates it: its
   confidence at least ``corroborated_confidence`` and its chi-square inside 95 %;
5. an ``operator_request`` when the skyline cannot be detected at the stop, or after
   ``max_rejections`` stops in a row without an accepted update; the traverse goes on with
   odometry.

The measurement functions are parameters (:class:`Measure`), so the loop runs the same on real
acquisitions and on scripted measurements (the tests).
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..errors import SkyfixError
from .ekf import CORROBORATION_CHI2, PoseFilter, fix_covariance
from .inputs import Traverse
from .output import Kind, begin_folder, canonical, digest, plan_folder

STOPS_FILE = "stops.jsonl"
#: what made the output (:func:`run_params`), written before its first stop
RUN_FILE = "run.json"

#: a traverse output, for :mod:`.output`: the parameters' names as the CLI's messages give them
OUTPUT = Kind(
    record=RUN_FILE, what="a traverse output", files=(STOPS_FILE, "track.geojson", "track.png"),
    folders=None, legacy=(STOPS_FILE,),
    labels={"stops": "the traverse's stops", "odometry_sha256": "the odometry (sha256)",
            "start": "the start (traverse.json)",
            "acquisitions_sha256": "the stops' acquisitions (sha256)",
            "dem_sha256": "the DEM (--dem, sha256)",
            "database_sha256": "the database (--db, sha256 of its build parameters)",
            "detector": "--detector", "dem_sigma_m": "--dem-sigma-m",
            "leg_length_m": "the leg length (--leg-length-m, else traverse.json's)",
            "min_confidence": "--min-confidence", "max_rejections": "--max-rejections",
            "format_version": "the record's version",
            "position_sigma": "what position_sigma_m means (radial since 2026-11-28, the worst "
                              "axis's before)"})


@dataclass(frozen=True)
class TraverseConfig:
    """min_confidence : an update below it is retried once, then used only where the track
        corroborates it: its confidence at least ``corroborated_confidence`` and its innovation
        inside the 95 % chi-square region (the confidence is the fix's own, with no prior; a
        fix 1 m off that the odometry's prediction agrees with is worth taking, with its sigma)
    max_rejections : stops in a row without an accepted update before the operator is asked
    heading_window_deg : [deg] the smallest half-window of a heading search
    max_position_sigma_m : [m] a position fix is due once the position's 1-sigma along its
        worst axis exceeds it (the heading at a wrong position is wrong by about sigma / skyline
        distance)
    min_fix_radius_m, max_fix_radius_m : [m] bounds of the position fix's search disc (3 sigma)
    position_sigma_floor_m, heading_sigma_floor_deg : [m], [deg] the least sigma a skyline
        measurement is given (skyfix's sigma is the fit's; the map's own errors come on top)
    leg_length_m : [m] overrides the traverse's own
    """

    min_confidence: float = 0.5
    corroborated_confidence: float = 0.25
    max_rejections: int = 3
    heading_window_deg: float = 10.0
    max_position_sigma_m: float = 15.0
    min_fix_radius_m: float = 15.0
    max_fix_radius_m: float = 150.0
    position_sigma_floor_m: float = 0.3
    heading_sigma_floor_deg: float = 0.05
    leg_length_m: float | None = None


@dataclass(frozen=True)
class Measurement:
    """One skyline measurement, grid north: x, y [m] (None for a heading), heading [deg], 1-sigmas,
    calibrated confidence, and the skyline's median distance [m] (for the heading's sensitivity to
    the position, where the heading's sigma does not already carry it; None when unknown or when
    it does)."""

    heading_deg: float
    heading_sigma_deg: float
    confidence: float
    x: float | None = None
    y: float | None = None
    position_sigma_m: float | None = None
    skyline_distance_m: float | None = None


@dataclass
class Measure:
    """heading(k, x, y, prior_deg, window_deg, position_sigma_m) (the track's position 1-sigma
    [m] at the stop) and fix(k, x, y, radius_m) -> :class:`Measurement` for stop k; either
    raises :class:`skyfix.errors.SkyfixError` when the stop's skyline cannot be used."""

    heading: Callable
    fix: Callable


def _fix_due(driven_m, leg_m, filt, cfg, owed, last) -> bool:
    # a leg ends where the odometry says it has driven the leg's length, to within the odometry's
    # own few per cent (else a 1000 m leg measured as 998 m waits one more stop); the traverse's
    # last stop ends the last leg
    return (owed or last or driven_m >= 0.97 * leg_m
            or filt.position_axis_sigma_m > cfg.max_position_sigma_m)


def _attempt_heading(measure, k, filt, cfg):
    window = max(cfg.heading_window_deg, 3.0 * filt.heading_sigma_deg)
    m = measure.heading(k, filt.state[0], filt.state[1], filt.state[2], min(window, 180.0),
                        filt.position_axis_sigma_m)
    retried = False
    if m.confidence < cfg.min_confidence and window < 180.0:
        retried = True  # the truth may lie outside the window, or the view was poor
        m2 = measure.heading(k, filt.state[0], filt.state[1], filt.state[2], min(2 * window, 180.0),
                             filt.position_axis_sigma_m)
        if m2.confidence > m.confidence:
            m = m2
    return m, retried


def _attempt_fix(measure, k, filt, cfg):
    r = float(np.clip(3.0 * filt.position_axis_sigma_m, cfg.min_fix_radius_m, cfg.max_fix_radius_m))
    m = measure.fix(k, filt.state[0], filt.state[1], r)
    retried = False
    if m.confidence < cfg.min_confidence and r < cfg.max_fix_radius_m:
        retried = True
        m2 = measure.fix(k, filt.state[0], filt.state[1], min(2 * r, cfg.max_fix_radius_m))
        if m2.confidence > m.confidence:
            m = m2
    return m, retried


def _apply(filt: PoseFilter, kind: str, m: Measurement, cfg) -> tuple[str, str, float | None]:
    """Update ``filt`` with measurement ``m`` of ``kind`` (``heading`` or ``position``) when it
    passes: its confidence, or the track's corroboration, and the innovation gate. Returns
    (update: ``kind`` or ``rejected``, reason ('' when taken plainly), chi-square or None)."""
    conf = m.confidence
    low = conf < cfg.min_confidence
    if conf < min(cfg.corroborated_confidence, cfg.min_confidence):
        return "rejected", f"confidence {conf:.2f} < {cfg.min_confidence}", None
    hs = _heading_sigma(m, filt, cfg)
    chi2 = CORROBORATION_CHI2 if low else None
    if kind == "position":
        ps = max(m.position_sigma_m, cfg.position_sigma_floor_m)
        u = filt.update_pose(m.x, m.y, m.heading_deg, ps, hs, chi2=chi2)
    else:
        u = filt.update_heading(m.heading_deg, hs, chi2=chi2)
    if low and u.accepted:
        return kind, (f"confidence {conf:.2f} < {cfg.min_confidence}, corroborated by the track "
                      f"(chi-square {u.nis:.1f} with {u.dof} dof, inside 95 %)"), u.nis
    if low:
        return "rejected", (f"confidence {conf:.2f} < {cfg.min_confidence} and not corroborated by "
                            f"the track (chi-square {u.nis:.1f} with {u.dof} dof, outside 95 %)"), u.nis
    if not u.accepted:
        return "rejected", (f"innovation outside the 99.9 % gate (chi-square {u.nis:.1f} with "
                            f"{u.dof} dof): the measurement disagrees with the track"), u.nis
    return kind, "", u.nis


def _heading_sigma(m: Measurement, filt: PoseFilter, cfg) -> float:
    s = max(m.heading_sigma_deg, cfg.heading_sigma_floor_deg)
    if m.x is None and m.skyline_distance_m:
        # measured at the predicted position by a measure that did not allow for its error: a
        # position error p moves the skyline by about p / d rad at distance d
        s = math.hypot(s, math.degrees(filt.position_axis_sigma_m / m.skyline_distance_m))
    return s


def _record(k, name, filt, convergence, **kw) -> dict:
    from ..north import heading_360, true_heading_deg

    x, y, h = (float(v) for v in filt.state)
    conv = convergence(x, y)
    d = {"stop": name, "index": k, "x": x, "y": y,
         "heading_deg": true_heading_deg(h, conv), "grid_heading_deg": heading_360(h), "meridian_convergence_deg": conv,
         "position_sigma_m": filt.position_sigma_m, "heading_sigma_deg": filt.heading_sigma_deg}
    d.update(kw)
    d["filter"] = {"state": [x, y, h], "cov": filt.cov.tolist()}
    return d


def convergence_function(crs_wkt: str) -> Callable:
    """``(x, y) -> meridian convergence [deg]`` (true minus grid north) in ``crs_wkt``; NaN where
    the CRS has no true north (a local engineering CRS, none at all), as in every other output:
    headings from true north are then the grid ones (:func:`~skyfix.north.true_heading_deg`), and
    a stop's record says the convergence is unknown rather than 0."""
    from ..north import meridian_convergence_deg

    def convergence(x, y):
        return meridian_convergence_deg(crs_wkt, x, y)

    return convergence


def read_done(path: Path, stops: list[str]) -> list[dict]:
    """The stop records already written (resume): whole lines only, in the traverse's order; a
    torn last line (the process killed mid-write) is dropped and rewritten."""
    if not path.is_file():
        return []
    done = []
    for line in path.read_text().splitlines():
        try:
            d = json.loads(line)
        except json.JSONDecodeError:
            break
        if len(done) >= len(stops) or d.get("stop") != stops[len(done)]:
            raise SkyfixError(f"{path} does not belong to this traverse (stop '{d.get('stop')}' "
                              f"where '{stops[len(done)] if len(done) < len(stops) else None}' "
                              "was expected): remove it, or pass another -o")
        done.append(d)
    return done


def _append(path: Path, rows: list[dict], d: dict) -> None:
    from .._io import write_jsonl

    rows.append(d)
    # rewritten whole and moved into place: a kill leaves the old file or the new, never a mix
    write_jsonl(path, rows)


def _stop_identity(folder) -> list | None:
    """A stop's acquisition as far as it decides the measurement, cheaply: its acquisition.json
    byte for byte and the size of every image it names (hashing every image of a long traverse
    would cost seconds at each start)."""
    if folder is None:
        return None
    folder = Path(folder)
    try:
        raw = (folder / "acquisition.json").read_bytes()
    except OSError:
        return None
    names = []
    try:
        d = json.loads(raw)
        names = [f.get("image") for f in d.get("frames") or []] + [(d.get("panorama") or {}).get("image")]
    except (ValueError, AttributeError, TypeError):
        pass  # a broken acquisition is refused by its own check; its bytes still identify it
    sizes = {n: (folder / n).stat().st_size for n in names
             if isinstance(n, str) and (folder / n).is_file()}
    return [hashlib.sha256(raw).hexdigest(), sizes]


def run_params(trav: Traverse, config: TraverseConfig, inputs: dict | None = None) -> dict:
    """What decides a traverse's output, recorded in ``run.json``: the traverse (its stops, the
    odometry, the start, each stop's acquisition), every setting of ``config`` (the leg length as
    used: ``config``'s, else the traverse's) and ``inputs``, what the measurements depend on that
    the loop cannot see (the DEM's and database's checksums, the detector, the map's sigma)."""
    cfg = asdict(config)
    cfg["leg_length_m"] = config.leg_length_m or trav.leg_length_m
    odo = [[o.forward_m, o.left_m, o.dheading_deg, np.asarray(o.cov).tolist()] for o in trav.odometry]
    return canonical({
        "stops": list(trav.stops), "odometry_sha256": digest(odo),
        "start": None if trav.start is None else asdict(trav.start),
        "acquisitions_sha256": digest([_stop_identity(f) for f in trav.folders]),
        # the records' position_sigma_m, and the start's and the fixes' as read: an output
        # written when they meant the worst axis is not resumed into radial lines
        "position_sigma": "radial", **cfg, **(inputs or {})})


def check_output(trav: Traverse, out_dir, *, config: TraverseConfig = TraverseConfig(),
                 inputs: dict | None = None, overwrite: bool = False,
                 afresh: str | None = "pass --overwrite to start afresh") -> str:
    """Refuse an ``out_dir`` that :func:`run_traverse` must not write (another run's output, a
    folder that is no traverse output) before any work; returns ``new``, ``resume`` or
    ``replace`` (``overwrite``). ``afresh``: how a refusal says to start afresh (None: no way
    but another -o)."""
    return _plan_output(trav, out_dir, run_params(trav, config, inputs), overwrite, afresh)


def _plan_output(trav: Traverse, out_dir, params: dict, overwrite: bool, afresh) -> str:
    action = plan_folder(out_dir, OUTPUT, params, overwrite=overwrite, afresh=afresh)
    if action == "resume":
        read_done(Path(out_dir) / STOPS_FILE, trav.stops)  # the lines themselves must fit too
    return action


def run_traverse(trav: Traverse, measure: Measure, out_dir, *, config: TraverseConfig = TraverseConfig(),
                 convergence: Callable = lambda x, y: 0.0, on_stop: Callable | None = None,
                 inputs: dict | None = None, about: dict | None = None,
                 overwrite: bool = False, afresh: str | None = "pass --overwrite to start afresh"
                 ) -> list[dict]:
    """Fuse the traverse's odometry with the skyline measurements; returns the stop records (also
    in ``out_dir/stops.jsonl``, one line per stop, appended as each stop ends; an interrupted run
    resumes at the first stop not written). ``convergence(x, y)`` [deg]: true minus grid north.

    ``out_dir/run.json`` records what made the output (:func:`run_params` with ``inputs``;
    ``about`` beside it, not compared): a rerun resumes only an output made with the same, and
    refuses any other (:func:`check_output`, ``afresh`` as there); ``overwrite`` starts afresh
    instead.
    """
    from ..north import grid_heading_from_true

    out_dir = Path(out_dir)
    # the parameters once: they read every stop's acquisition.json and its images' sizes
    params = run_params(trav, config, inputs)
    begin_folder(out_dir, OUTPUT, params, _plan_output(trav, out_dir, params, overwrite, afresh),
                 about)
    path = out_dir / STOPS_FILE
    rows = read_done(path, trav.stops)
    leg_m = config.leg_length_m or trav.leg_length_m
    if rows:
        last = rows[-1]
        filt = PoseFilter(*last["filter"]["state"], last["filter"]["cov"])
        driven, owed, misses = last["since_fix_m"], last["fix_owed"], last["misses_in_a_row"]
        fix_misses = last.get("fix_misses_in_a_row", 0)
    else:
        filt, driven, owed, misses, fix_misses = None, 0.0, False, 0, 0
    for k in range(len(rows), len(trav.stops)):
        name = trav.stops[k]
        if k == 0:
            s = trav.start
            if s is not None:
                h = grid_heading_from_true(s.heading_deg, convergence(s.x, s.y))
                filt = PoseFilter(s.x, s.y, h, fix_covariance(s.position_sigma_m,
                                                              s.heading_sigma_deg))
        else:
            filt.predict(trav.odometry[k - 1])
            driven += trav.odometry[k - 1].distance_m
        last = k == len(trav.stops) - 1 and k > 0
        kind = ("position" if filt is None or _fix_due(driven, leg_m, filt, config, owed, last)
                else "heading")
        t0 = time.perf_counter()
        update, conf, request, reason, nis, retried = "none", None, None, "", None, False
        measured = None
        try:
            if filt is None:  # no start: a global fix (the measurement function knows no prior)
                measured = measure.fix(k, None, None, None)
                if measured.confidence < config.min_confidence:
                    raise SkyfixError(f"the first stop's fix has confidence {measured.confidence:.2f}: "
                                      "no start to go on from")
                filt = PoseFilter(measured.x, measured.y, measured.heading_deg, fix_covariance(
                    max(measured.position_sigma_m, config.position_sigma_floor_m),
                    max(measured.heading_sigma_deg, config.heading_sigma_floor_deg)))
                update, conf = "position", measured.confidence
            else:
                fix_failed = None
                try:
                    if kind == "position":
                        measured, retried = _attempt_fix(measure, k, filt, config)
                    else:
                        measured, retried = _attempt_heading(measure, k, filt, config)
                except SkyfixError as e:
                    if kind != "position":
                        raise
                    # a skyline too narrow for a search (under 20 bins) still gives a heading
                    fix_failed = f"position fix failed ({str(e).splitlines()[0]})"
                else:
                    conf = measured.confidence
                    update, reason, nis = _apply(filt, kind, measured, config)
                    if kind == "position" and update == "rejected":
                        fix_failed = f"position fix rejected ({reason})"
                if fix_failed is not None:
                    # the fix stays owed, but the heading need not drift meanwhile: the stop's
                    # skyline still gives one at the predicted position
                    measured, _ = _attempt_heading(measure, k, filt, config)
                    conf = measured.confidence
                    update, reason, nis = _apply(filt, "heading", measured, config)
                    reason = (f"{fix_failed}; heading "
                              + ("taken" + (f": {reason}" if reason else "") if update == "heading"
                                 else f"rejected too: {reason}"))
        except SkyfixError as e:
            if filt is None:
                raise SkyfixError(f"stop '{name}': {e}") from None
            update, reason = "none", str(e).splitlines()[0]
            request = {"reason": f"no usable skyline at this stop: {reason}",
                       "help": "draw the skyline by hand in one image, or drive on to where the "
                               "skyline is clearer and acquire again"}
        if update in ("heading", "position"):
            misses = 0
            if update == "position":
                driven, owed, fix_misses = 0.0, False, 0
        else:
            misses += 1
        if kind == "position" and update != "position":
            owed = True  # the fix is still due at the next stop
            fix_misses += 1
        if request is None and (misses >= config.max_rejections
                                or fix_misses >= config.max_rejections):
            what = (f"{misses} stops in a row without an accepted skyline update"
                    if misses >= config.max_rejections else
                    f"{fix_misses} position fixes in a row not taken")
            request = {"reason": f"{what} (last: {reason})",
                       "help": "check the skyline detections, draw one by hand, or move the "
                               "rover where the skyline is clearer; the position is "
                               f"odometry only, 1-sigma {filt.position_sigma_m:.1f} m"}
        after = 0 if request is not None else misses  # asked: the counts start again
        fix_after = 0 if request is not None else fix_misses
        meas = None
        if measured is not None:
            meas = {"heading_deg_grid": measured.heading_deg, "heading_sigma_deg": measured.heading_sigma_deg,
                    "x": measured.x, "y": measured.y, "position_sigma_m": measured.position_sigma_m}
        d = _record(k, name, filt, convergence, update=update, attempted=kind,
                    confidence=conf, nis=nis, retried=retried, reason=reason or None,
                    operator_request=request, measurement=meas, since_fix_m=driven,
                    fix_owed=owed, misses_in_a_row=after, fix_misses_in_a_row=fix_after,
                    seconds=round(time.perf_counter() - t0, 3))
        _append(path, rows, d)
        misses, fix_misses = after, fix_after
        if on_stop is not None:
            on_stop(k, d)
    return rows

