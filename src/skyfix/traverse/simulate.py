"""A simulated traverse: a smooth path over a DEM, an acquisition from the simulator at every stop,
odometry with drift between the stops, and the truth.

The rover at stop k faces ``h_k``; it turns by ``dh_k`` and drives ``s`` metres straight on to stop
k + 1. In stop k's body frame that is forward ``s cos dh``, left ``-s sin dh`` and a heading change
``dh`` (headings clockwise). The odometry it reports adds, per step, N(0, drift s) to forward and
left and N(0, heading drift * sqrt(s / 100 m)) to the heading change, and says those sigmas. The
heading's is a random walk: after any 100 m its 1-sigma is the heading drift, whatever the stop
spacing (a per-step sigma of ``drift * s / 100`` gave 0.35 deg per 100 m at 50 m stops for a
drift of 0.5, and 0.16 at 10 m).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from ..north import wrap_deg
from .inputs import ODOMETRY_FILE, TRAVERSE_FILE, TRUTH_FILE
from .output import Kind, begin_folder, plan_folder


@dataclass(frozen=True)
class TraversePlan:
    """Stops (x, y) [m] and headings [deg from grid north], and the true odometry steps
    (forward, left [m], dheading [deg])."""

    x: np.ndarray
    y: np.ndarray
    heading_deg: np.ndarray
    steps: np.ndarray


def plan_path(dem, length_m: float, spacing_m: float, seed: int, *, margin_m: float | None = None,
              turn_sigma_deg: float = 8.0) -> TraversePlan:
    """A random smooth path of ``length_m`` [m] with a stop every ``spacing_m`` [m], kept at least
    ``margin_m`` [m] (default: a fifth of the DEM's smaller side, at most 3 km) inside the DEM."""
    if not (math.isfinite(length_m) and length_m > 0 and math.isfinite(spacing_m) and 0 < spacing_m <= length_m):
        raise ParameterError(f"need 0 < stop spacing <= length, got {spacing_m} and {length_m} m")
    x0, y0, x1, y1 = dem.bounds
    if margin_m is None:
        margin_m = min(0.2 * min(x1 - x0, y1 - y0), 3000.0)
    lo = np.array([x0 + margin_m, y0 + margin_m])
    hi = np.array([x1 - margin_m, y1 - margin_m])
    if np.any(hi - lo < 2 * spacing_m):
        raise ParameterError("the DEM is too small for this traverse's margin and spacing")
    rng = np.random.default_rng(seed)
    n = int(round(length_m / spacing_m)) + 1
    # a reprojected DEM's corners hold no terrain: every stop stands on a height
    def on_dem(q):
        return bool(np.all(q >= lo) and np.all(q <= hi) and np.isfinite(dem.height_at(q[0], q[1])))

    p = rng.uniform(lo, hi)
    for _try in range(1000):
        if on_dem(p):
            break
        p = rng.uniform(lo, hi)
    else:
        raise ParameterError("found no place with a height to start the traverse: the DEM is mostly "
                             "void or around its data")
    h = rng.uniform(0.0, 360.0)
    xs, ys, hs, steps = [p[0]], [p[1]], [h], []
    centre = (lo + hi) / 2
    for _ in range(n - 1):
        turn = rng.normal(0.0, turn_sigma_deg)
        for _try in range(36):
            h2 = h + turn
            q = p + spacing_m * np.array([math.sin(math.radians(h2)), math.cos(math.radians(h2))])
            if on_dem(q):
                break
            # steer towards the centre: the turn that heads there, plus a little noise
            to_c = math.degrees(math.atan2(centre[0] - p[0], centre[1] - p[1]))
            turn = wrap_deg(to_c - h) * 0.5 + rng.normal(0.0, turn_sigma_deg)
        dh = turn
        steps.append((spacing_m * math.cos(math.radians(dh)), -spacing_m * math.sin(math.radians(dh)), dh))
        h = (h + dh) % 360.0
        p = q
        xs.append(p[0])
        ys.append(p[1])
        hs.append(h)
    return TraversePlan(np.array(xs), np.array(ys), np.array(hs), np.array(steps).reshape(-1, 3))


def parse_stop_conditions(items) -> dict:
    """``["12=clouds:1", "20=dark"]`` -> {12: "clouds:1", 20: "dark"}; the conditions' names and
    strengths are checked here, before anything is simulated (the stop numbers, once the
    traverse's length is known: :func:`simulate_traverse`)."""
    from ..simulate import Conditions

    out = {}
    for it in items or ():
        k, sep, cond = str(it).partition("=")
        if not sep or not k.strip().isdigit() or not cond.strip():
            raise ParameterError(f"stop condition '{it}': write STOP=CONDITIONS, e.g. 12=clouds:1")
        try:
            Conditions.parse(cond)
        except ParameterError as e:
            # without the example, which names simulate's --conditions
            raise ParameterError(f"stop condition '{it}': {str(e).split(' (e.g.')[0]}") from None
        if int(k) in out:
            raise ParameterError(f"stop {int(k)} has two --stop-conditions: give its conditions "
                                 "once, comma-separated (e.g. 12=clouds:1,dust:0.5)")
        out[int(k)] = cond.strip()
    return out


#: the simulation's parameters (``simulation.json``), for :mod:`.output`, named as the CLI's
#: messages name them
SIMULATION = Kind(
    record="simulation.json", what="a simulated traverse",
    files=(TRAVERSE_FILE, ODOMETRY_FILE, TRUTH_FILE), folders=r"stop_\d+",
    legacy=(TRAVERSE_FILE, ODOMETRY_FILE, TRUTH_FILE, "stop_000"),
    labels={"map_sha256": "the DEM (sha256)", "seed": "--seed", "length_m": "--length-m",
            "stop_spacing_m": "--stop-spacing-m", "stop_conditions": "--stop-conditions",
            "mode": "--mode", "pano_size": "--pano-size", "distance_drift": "--distance-drift",
            "heading_drift_deg_per_100m": "--heading-drift-deg-per-100m",
            "leg_length_m": "--leg-length-m", "start_sigmas": "the start (--no-start)",
            "map_errors": "--map-errors", "world_sha256": "--world-dem (sha256)"})


def simulate_traverse(dem, out, *, length_m=3000.0, stop_spacing_m=50.0, seed=0,
                      distance_drift=0.02, heading_drift_deg_per_100m=0.5,
                      stop_conditions: dict | None = None, camera="navcam", mode="frames",
                      pano_size=(2048, 512), tilt_deg=15.0, camera_height_m=1.5, planet=None,
                      start_sigmas=(2.0, 1.0), with_start=True, leg_length_m=1000.0,
                      map_errors=None, world=None, on_stop=None, overwrite=False,
                      afresh="pass --overwrite to start afresh") -> Path:
    """Write a traverse folder ``out`` (``docs/conventions.md``, "Traverse"): ``stop_NNN/``
    acquisitions, ``odometry.jsonl``, ``traverse.json`` (the start: the truth on the map blurred by
    ``start_sigmas`` = (position [m], radial; heading [deg]) 1-sigma), ``truth.jsonl``.

    Every parameter is checked before ``out`` is touched. ``simulation.json`` records them before
    the first stop is rendered: a rerun with the same ones resumes (a stop already rendered is
    kept); one with others is refused, as is a non-empty ``out`` that is no simulated traverse,
    unless ``overwrite`` (then what an earlier simulation wrote in ``out`` is deleted first).
    ``afresh``: how a refusal tells the user to start afresh (None: no way but another -o).

    map_errors : render every stop from :func:`skyfix.simulate.world.world_dem` of ``dem`` with
        these errors (:class:`skyfix.simulate.MapErrors`), one world drawn from ``seed``;
        ``traverse.json`` records them and the map offset (truth to where the truth's terrain lies
        on the map), which :func:`map_offset_of` reads back
    world : render from this DEM instead (any second DEM of the same place, in ``dem``'s CRS)

    The path is planned on ``dem`` (the map); ``truth.jsonl`` is where the rover is in the world.
    """
    from ..formats import Truth
    from ..north import true_heading_deg
    from ..planets import resolve_planet
    from ..simulate import as_conditions, check_render_options, check_seed, simulate_acquisition
    from ..simulate.conditions import check_planet
    from ..simulate.world import (check_world_covers, check_world_heights, recorded_map_offset,
                                  world_dem,
                                  world_record)
    from .run import convergence_function

    seed = check_seed(seed)
    out = Path(out)
    stop_conditions = dict(stop_conditions or {})
    if map_errors is not None and world is not None:
        raise ParameterError("give map errors or a world DEM, not both")
    # refused now, not at the first stop (or the one with the condition) with stops on disk
    check_render_options(mode=mode, camera=camera, camera_height_m=camera_height_m,
                         tilt_deg=tilt_deg if mode == "frames" else 0.0, planet=planet, seed=seed,
                         pano_size=pano_size)
    for name, v, ok, want in (
            ("distance drift", distance_drift, 0 <= distance_drift < 1, "a share in [0, 1)"),
            ("heading drift", heading_drift_deg_per_100m, heading_drift_deg_per_100m >= 0,
             "a finite number of deg / 100 m >= 0"),
            ("leg length", leg_length_m, leg_length_m > 0, "a finite number of metres > 0")):
        if not (math.isfinite(v) and ok):
            raise ParameterError(f"the {name} must be {want}, got {v}")
    pl = resolve_planet(planet, getattr(dem, "body", None))
    conds = {k: as_conditions(c) for k, c in stop_conditions.items()}
    for k, c in sorted(conds.items()):
        try:
            check_planet(c, pl.name if pl.name in ("earth", "mars") else "earth")
        except ParameterError as e:
            # check_planet's advice names simulate's --planet, which simulate-traverse lacks
            raise ParameterError(f"stop {k}'s conditions ({c}): {str(e).split(':')[0]}, and this "
                                 f"DEM is on {pl.name}: drop it") from None
    plan = plan_path(dem, length_m, stop_spacing_m, seed)
    n = plan.x.size
    if world is not None:
        check_world_covers(world, (plan.x.min(), plan.y.min(), plan.x.max(), plan.y.max()),
                           "the traverse's stops on the map", "a shorter traverse (--length-m) "
                           "or another --seed")
        check_world_heights(world, plan.x, plan.y, "stops", "a shorter traverse (--length-m) or "
                            "another --seed")
    bad = [k for k in stop_conditions if not 0 <= k < n]
    if bad:
        raise ParameterError(f"stop conditions for stops {bad}: the traverse has stops 0-{n - 1} "
                             "(a stop every stop spacing along the length, from 0): renumber them "
                             "or lengthen the traverse")
    names = [f"stop_{k:03d}" for k in range(n)]
    params = {"map_sha256": dem.checksum, "seed": seed, "length_m": length_m,
              "stop_spacing_m": stop_spacing_m,
              "stop_conditions": {names[k]: str(c) for k, c in sorted(conds.items())},
              "mode": mode, "camera_height_m": camera_height_m, "planet": pl.to_attr(),
              "distance_drift": distance_drift,
              "heading_drift_deg_per_100m": heading_drift_deg_per_100m,
              "leg_length_m": leg_length_m,
              "start_sigmas": list(start_sigmas) if with_start else None,
              "map_errors": None if map_errors is None else map_errors.to_dict(),
              "world_sha256": None if world is None else world.checksum}
    if mode == "frames":  # what the other mode ignores is not the simulation's
        params.update(camera=camera if isinstance(camera, str) else repr(camera), tilt_deg=tilt_deg)
    else:
        params["pano_size"] = [int(v) for v in pano_size]
    action = plan_folder(out, SIMULATION, params, overwrite=overwrite, afresh=afresh)
    rng = np.random.default_rng(seed + 1)
    sim_world = world_record(map_errors, seed, world)
    offset = recorded_map_offset(sim_world)
    render = dem
    begin_folder(out, SIMULATION, params, action,
                 about={"map": getattr(dem, "source", ""),
                        "world": None if world is None else getattr(world, "source", "")})
    convergence = convergence_function(dem.crs_wkt)
    conv = [convergence(x, y) for x, y in zip(plan.x, plan.y)]
    for k in range(n):
        folder = out / names[k]
        if not (folder / "acquisition.json").is_file():
            if render is dem and (world is not None or map_errors is not None):
                # drawn once, and only when a stop is still to render (a resumed run skips it)
                render = world if world is not None else world_dem(dem, map_errors, seed)
            simulate_acquisition(render, Truth(float(plan.x[k]), float(plan.y[k]), float(plan.heading_deg[k])),
                                 folder, camera=camera, mode=mode, pano_size=tuple(pano_size),
                                 tilt_deg=tilt_deg if mode == "frames" else 0.0,
                                 camera_height_m=camera_height_m, planet=planet,
                                 conditions=stop_conditions.get(k), seed=seed * 1000 + k,
                                 simulation_meta=sim_world)
        if on_stop is not None:
            on_stop(k, n)
    s = stop_spacing_m
    sig = (distance_drift * s, distance_drift * s, heading_drift_deg_per_100m * math.sqrt(s / 100.0))
    lines = []
    for k, (f, l_, dh) in enumerate(plan.steps):
        lines.append({"from": names[k], "to": names[k + 1],
                      "forward_m": f + rng.normal(0, sig[0]), "left_m": l_ + rng.normal(0, sig[1]),
                      "dheading_deg": dh + rng.normal(0, sig[2]),
                      "sigma_forward_m": sig[0], "sigma_left_m": sig[1], "sigma_heading_deg": sig[2]})
    truth = [{"stop": names[k], "x": float(plan.x[k]), "y": float(plan.y[k]),
              "heading_deg": true_heading_deg(float(plan.heading_deg[k]), conv[k])}
             for k in range(n)]
    meta = {"stops": names, "leg_length_m": leg_length_m,
            "simulation": {"seed": seed, "length_m": length_m, "stop_spacing_m": stop_spacing_m,
                           "distance_drift": distance_drift,
                           "heading_drift_deg_per_100m": heading_drift_deg_per_100m,
                           "stop_conditions": {names[k]: c for k, c in sorted(stop_conditions.items())},
                           **sim_world}}
    if with_start:
        ps, hsd = start_sigmas
        # a start fix is a fix on the map: where the truth's terrain lies there
        # ps is radial, as every position sigma skyfix reads or writes: ps / sqrt(2) an axis
        meta["start"] = {"x": float(plan.x[0] + offset[0] + rng.normal(0, ps / math.sqrt(2.0))),
                         "y": float(plan.y[0] + offset[1] + rng.normal(0, ps / math.sqrt(2.0))),
                         "heading_deg": truth[0]["heading_deg"] + float(rng.normal(0, hsd)),
                         "position_sigma_m": ps, "heading_sigma_deg": hsd}
    from .._io import write_json, write_jsonl

    write_jsonl(out / ODOMETRY_FILE, lines)
    write_jsonl(out / TRUTH_FILE, truth)
    write_json(out / TRAVERSE_FILE, meta)
    return out


def map_offset_of(trav) -> tuple[float, float]:
    """(dx, dy) [m] from a simulated traverse's truth to where its terrain lies on the map (0, 0
    when the world was the map, or for a traverse that is not simulated)."""
    from ..simulate.world import recorded_map_offset

    return recorded_map_offset((getattr(trav, "meta", None) or {}).get("simulation"))


def odometry_only(trav, convergence=lambda x, y: 0.0) -> list[tuple[float, float, float]]:
    """Dead reckoning from the start along the reported odometry: (x, y, grid heading) per stop;
    ``convergence(x, y)`` [deg] true minus grid north."""
    from ..north import grid_heading_from_true
    from .ekf import PoseFilter

    s = trav.start
    f = PoseFilter(s.x, s.y, grid_heading_from_true(s.heading_deg, convergence(s.x, s.y)), np.eye(3))
    out = [tuple(f.state)]
    for o in trav.odometry:
        f.predict(o)
        out.append(tuple(f.state))
    return out


def read_truth(root) -> list[dict]:
    return [json.loads(line) for line in (Path(root) / TRUTH_FILE).read_text().splitlines() if line]
