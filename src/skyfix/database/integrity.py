"""What state a store on disk is in: its root metadata and attributes checked by kind, the arrays
against the grid, which blocks are built and intact (a marker and every chunk file present), which
have their coarse index, and the clean-up of partial writes. Every read and every resume starts
here, so that a damaged or foreign folder is refused by name rather than read wrong.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from ..errors import DatabaseError
from .layout import (COARSE, COARSE_FACTOR, COARSE_STRIDE, DATA_ARRAYS, FORMAT, Grid, MARKER_DIR,
                     array_sha256, coarse_shape, has_coarse_layout, read_marker)


def root_state(path: Path) -> tuple[str, dict | str | None]:
    """What ``path/zarr.json`` says: ``("ok", attrs)`` for a skyfix database, ``("damaged", why)``
    for a zarr.json that exists but cannot be read (or is gone from beside our block markers),
    ``("none", None)`` otherwise."""
    f = path / "zarr.json"
    if not f.is_file():
        if (path / MARKER_DIR).is_dir():  # our bookkeeping is there: a database that lost its root
            return "damaged", f"{f} is missing"
        return "none", None
    try:
        meta = json.loads(f.read_text())
    except (OSError, ValueError) as e:  # truncated, empty, binary garbage, unreadable
        why = "it is empty" if f.stat().st_size == 0 else f"{type(e).__name__}: {e}"
        return "damaged", f"{f} cannot be read ({why})"
    if not isinstance(meta, dict):
        return "damaged", f"{f} holds a JSON {type(meta).__name__}, not an object"
    attrs = meta.get("attributes")
    if not isinstance(attrs, dict) or attrs.get("format") != FORMAT:
        return "none", None
    return "ok", attrs


# What each recorded attribute must be: (dotted key, kind). Checked when a database is opened, so
# that a hand-edited or corrupted zarr.json is named instead of failing deep in a computation.
_ATTR_KINDS = (
    ("grid", "object"), ("grid.x0", "number"), ("grid.y0", "number"), ("grid.spacing_m", "positive"),
    ("grid.shape", "pair"), ("grid.block_shape", "pair"), ("azimuth_bins", "count"),
    ("camera_height_m", "number"), ("max_distance_m", "number or null"), ("planet", "object"),
    ("planet.name", "text"), ("planet.radius_m", "positive"), ("planet.refraction_k", "number"),
    ("elevation", "object"), ("elevation.scale_deg", "positive"), ("elevation.missing", "integer"),
    ("dem", "object"), ("dem.sha256", "text"), ("dem.source", "text"), ("crs_wkt", "text"),
    ("build", "object"),
)


_KIND_WORDS = {"object": "an object", "number": "a number", "positive": "a number > 0",
               "count": "a whole number > 0", "integer": "a whole number",
               "pair": "two whole numbers > 0", "text": "a string", "number or null": "a number or null"}


def is_int(v) -> bool:
    """True for a JSON integer (a bool is not one)."""
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _attr_ok(kind: str, v) -> bool:
    if kind == "object":
        return isinstance(v, dict)
    if kind == "number":
        return _is_number(v)
    if kind == "positive":
        return _is_number(v) and v > 0
    if kind == "number or null":
        return v is None or _is_number(v)
    if kind == "count":
        return is_int(v) and v > 0
    if kind == "integer":
        return is_int(v)
    if kind == "pair":
        return isinstance(v, list) and len(v) == 2 and all(is_int(x) and x > 0 for x in v)
    return isinstance(v, str)


def damaged(path, what: str) -> DatabaseError:
    """The error for a store whose metadata was edited or corrupted, saying how to rebuild it."""
    return DatabaseError(f"{path}: database metadata damaged: {what} (its zarr.json was edited or "
                         "corrupted): rebuild it with `skyfix build-db ... --overwrite`")


def check_attrs(path: Path, attrs: dict) -> None:
    """Raise a DatabaseError naming the first recorded attribute of the wrong type."""
    for key, kind in _ATTR_KINDS:
        v = attrs
        for part in key.split("."):
            if part not in v:
                raise damaged(path, f"{key} is missing")
            v = v[part]
        if not _attr_ok(kind, v):
            raise damaged(path, f"{key} must be {_KIND_WORDS[kind]}, got {v!r}")


def check_build_record(path: Path, attrs: dict) -> None:
    """The geometry a search reads (``grid``, ``elevation.scale_deg``, the bins, the camera) must be
    what the build record says was built: an edited ``grid.spacing_m`` or ``x0`` made ``locate``
    answer from the wrong geometry without a word (``verify --samples 0`` passed it)."""
    build = attrs.get("build")
    if not isinstance(build, dict):
        return  # a store from before the build record: nothing to compare with
    try:
        want = Grid.from_bounds(build["bounds"], build["spacing_m"],
                                build.get("block_positions", attrs["grid"]["block_shape"][0])).to_attr()
    except Exception as e:  # noqa: BLE001 - a damaged record, whatever its fault
        raise damaged(path, f"its build record cannot be read ({type(e).__name__}: {e})") from None
    said = {f"grid.{k}": (attrs["grid"].get(k), want[k])
            for k in ("x0", "y0", "spacing_m", "shape", "block_shape")}
    said["elevation.scale_deg"] = (attrs["elevation"].get("scale_deg"), build.get("scale_deg"))
    for k in ("azimuth_bins", "camera_height_m", "max_distance_m", "planet"):
        said[k] = (attrs.get(k), build.get(k))
    wrong = [f"{k} {a!r} (the build made {b!r})" for k, (a, b) in said.items()
             if b is not None and a != b and not (isinstance(a, (int, float)) and isinstance(b, (int, float))
                                                  and math.isclose(a, b, rel_tol=1e-12))]
    if wrong:
        raise damaged(path, "its metadata disagrees with its build record: " + "; ".join(wrong))


def check_arrays(path: Path, g, attrs: dict) -> None:
    """The arrays' own metadata must agree with the recorded grid (one chunk per block)."""
    ny, nx = attrs["grid"]["shape"]
    b = attrs["grid"]["block_shape"][0]
    bins = attrs["azimuth_bins"]
    for name in DATA_ARRAYS:
        a = g[name]
        want = (ny, nx, bins) if name == "elevation" else (ny, nx)
        chunks = (b, b, bins) if name == "elevation" else (b, b)
        if tuple(a.shape) != want or tuple(a.chunks) != chunks:
            raise damaged(path, f"array {name} has shape {tuple(a.shape)} in chunks {tuple(a.chunks)}, "
                                 f"but grid.shape {[ny, nx]}, grid.block_shape and azimuth_bins {bins} "
                                 f"say {want} in chunks {chunks}")


def chunk_keys(root: Path) -> set[str]:
    """Every file under ``root`` as a '/'-separated path relative to it (one listing, no reads)."""
    have = set()
    for d, _, files in os.walk(root):
        rel = os.path.relpath(d, root).replace(os.sep, "/")
        pre = "" if rel == "." else rel + "/"
        have.update(pre + f for f in files)
    return have


def absent_data(path: Path, g, grid: Grid, done) -> dict:
    """Built blocks (with a marker) whose chunk file of some array is gone: {(br, bc): [names]}.

    zarr reads an absent chunk as the fill value without a word, so a deleted chunk file would
    read as a block of "no terrain" skylines and NaN heights. One directory listing per array at
    open time finds them (milliseconds for a 7 x 7 km database), so a read costs one set lookup.
    """
    blocks = sorted(set(done) & set(grid.blocks()))
    absent: dict = {}
    for name in DATA_ARRAYS:
        a = g[name]
        have = chunk_keys(path / name)
        enc = a.metadata.chunk_key_encoding
        tail = (0,) * (a.ndim - 2)
        for br, bc in blocks:
            if enc.encode_chunk_key((br, bc) + tail) not in have:
                absent.setdefault((br, bc), []).append(name)
    # zarr does not write a chunk that is all fill value: legitimate if the marker's checksum says
    # the block really was all fill (only conceivable for elevation: every ray without terrain).
    for (br, bc), names in list(absent.items()):
        try:
            sha = (read_marker(path, br, bc) or {})["sha256"]
        except (OSError, ValueError, KeyError, TypeError):
            sha = {}
        rs, cs = grid.block_slices(br, bc)
        gone = []
        for name in names:
            a = g[name]
            fill = np.full((rs.stop - rs.start, cs.stop - cs.start) + tuple(a.shape[2:]), a.fill_value,
                           a.dtype)
            if not isinstance(sha, dict) or sha.get(name) != array_sha256(fill):
                gone.append(name)
        if gone:
            absent[(br, bc)] = gone
        else:
            del absent[(br, bc)]
    return absent


def intact_blocks(path: Path, grid: Grid) -> set[tuple[int, int]]:
    """Blocks of ``grid`` with a readable marker and every chunk file: a resume redoes the others
    (a marker folder named for a block outside the grid counts for none, as when the store is
    opened). Raises :class:`DatabaseError` for a store whose arrays cannot be opened (their
    metadata gone): taking every marked block as built then called it complete."""
    import zarr

    done = set()
    for br, bc in done_blocks(path) & set(grid.blocks()):
        try:
            read_marker(path, br, bc)
        except (OSError, ValueError):
            continue
        done.add((br, bc))
    try:
        g = zarr.open_group(str(path), mode="r")
        for name in DATA_ARRAYS:
            g[name]
        absent = absent_data(path, g, grid, done)
    except Exception as e:  # zarr raises several unrelated types for a broken store
        raise DatabaseError(f"{path} is a skyfix database whose arrays cannot be opened "
                            f"({type(e).__name__}: {e}): pass --overwrite to rebuild it from "
                            "scratch") from None
    return done - set(absent)


def data_missing_message(path, absent: dict) -> str:
    """What to tell a user when built blocks lack chunk files (``absent``: block -> array names)."""
    (br, bc), names = min(absent.items())
    more = f" ({len(absent)} blocks in all)" if len(absent) > 1 else ""
    return (f"{path}: block ({br}, {bc}) data missing (no chunk file for {', '.join(names)}){more}: "
            f"run `skyfix verify {path}`, then rebuild (the same build-db command resumes and redoes "
            "such blocks)")


def done_blocks(path) -> set[tuple[int, int]]:
    """Blocks (br, bc) whose marker exists, i.e. whose data were fully written."""
    d = Path(path) / MARKER_DIR
    out = set()
    if d.is_dir():
        for p in d.iterdir():
            n = p.name
            # a group rRRRR_cCCCC/ with its zarr.json, or (older stores) a file rRRRR_cCCCC.json
            done = (p / "zarr.json").is_file() if p.is_dir() else n.endswith(".json")
            if done and n.startswith("r") and n[5:7] == "_c":
                try:
                    out.add((int(n[1:5]), int(n[7:11])))
                except ValueError:
                    pass
    return out


def clean_partials(path: Path) -> int:
    """Remove temporary files a killed build left behind (zarr's ``*.partial``, our ``.name.*``)."""
    n = 0
    for d, _, files in os.walk(path):
        for f in files:
            if f.endswith(".partial") or f.startswith("."):
                os.unlink(os.path.join(d, f))
                n += 1
    return n


def coarse_array_ok(group, grid: Grid, bins: int) -> bool:
    """Whether the group holds a ``coarse`` array of the shape and chunks this grid needs."""
    if not has_coarse_layout(grid.block, bins):
        return False
    try:
        a = group[COARSE]
    except KeyError:
        return False
    b = grid.block // COARSE_STRIDE
    return (tuple(a.shape) == coarse_shape(grid, bins) and str(a.dtype) == "int16"
            and tuple(a.chunks) == (b, b, bins // COARSE_FACTOR))


def indexed_blocks(path, group, grid: Grid, bins: int) -> set[tuple[int, int]]:
    """Blocks whose coarse chunk file is there (one listing of the array's folder); empty when the
    store has no usable ``coarse`` array."""
    if not coarse_array_ok(group, grid, bins):
        return set()
    have = chunk_keys(Path(path) / COARSE)
    key = group[COARSE].metadata.encode_chunk_key
    return {(br, bc) for br, bc in grid.blocks() if key((br, bc, 0)) in have}


def check_dem_crs(db, dem, db_path, dem_path) -> None:
    """Refuse a DEM read into another work CRS than the one the database ``db`` was built in:
    its positions would be read as coordinates of another map. The DEM file can be the very one
    (same checksum) and still differ here: skyfix before 2026-11-28 kept a DEM projected with
    0.1-1 % scale error (the Sierra's USA Albers) in its own CRS, and now reads it into its UTM
    zone. A :class:`~skyfix.errors.DatabaseError` naming both and what to do."""
    from pyproj import CRS

    if not getattr(db, "crs_wkt", "") or dem is None or not dem.crs_wkt:
        return
    built, read = CRS.from_wkt(db.crs_wkt), CRS.from_wkt(dem.crs_wkt)
    if built == read:
        _check_dem_grid(db, dem, db_path, dem_path)
        return
    raise DatabaseError(
        f"the database {db_path} was built in {db.attrs.get('crs_name') or built.name}, but --dem "
        f"{dem_path} is read in {dem.crs_name or read.name}: its positions would be taken for "
        "another map's. Rebuild the database from this DEM with this skyfix (build-db; bounds in "
        "the DEM's work CRS, which `skyfix info DEM` prints)")


def _check_dem_grid(db, dem, db_path, dem_path) -> None:
    """The very DEM file, read into another grid than the database was built on: skyfix before
    2026-11-28 cropped a reprojected DEM to the largest rectangle inside its footprint (70 % of
    the Sierra DEM), and now keeps all of it. The database's skylines then miss the terrain the
    crop cut, which no later check would notice (the file's checksum is the same)."""
    rec = db.attrs.get("dem") or {}
    shape, bounds = rec.get("shape"), rec.get("bounds")
    if not shape or not bounds or rec.get("sha256") != getattr(dem, "checksum", None):
        return
    if list(shape) == list(dem.shape) and all(abs(a - b) < 1e-3 for a, b in zip(bounds, dem.bounds)):
        return
    raise DatabaseError(
        f"the database {db_path} was built on {dem_path} read as a {shape[1]} x {shape[0]} grid, "
        f"which this skyfix reads as {dem.shape[1]} x {dem.shape[0]} (before 2026-11-28 a "
        "reprojected DEM was cropped to the largest rectangle inside it, and the skylines stored miss "
        "the terrain cut off): rebuild the database from this DEM with this skyfix (build-db)")
