"""The skyline chunks decoded without zarr's codec pipeline.

A full search of the 7 x 7 km database decodes 1.4 GB of int16 skylines. Through zarr that cost
4.5 s of CPU, three times the zstd decompression it wraps: the pipeline runs each codec as its
own pass (the shuffle, then the delta filter's cumulative sum) behind asyncio. Here the chunk
file is read, zstd decompresses it (its checksum checked) and one numba pass undoes the shuffle
and the delta together: 1.9 s of the search's reader thread for the same data
(``benchmarks/bench_locate.py``), the arrays identical.

Only the layouts skyfix writes take this path (:func:`skyline_codecs`, for ``elevation`` and the
coarse index: optionally Transpose to (azimuth, y, x), then Delta(i2), little-endian bytes,
Shuffle(2), zstd; regular chunks, default chunk keys, a local folder). Any other array, and a
big-endian machine, is read through zarr: a chain edited in a store's zarr.json (reordered, a
codec dropped, added or set otherwise) is decoded as its metadata says, the same for the search
and ``skyfix verify``, rather than refused here; what it decodes to is then judged by the blocks'
checksums like any other damage, and a store another tool wrote with other codecs still reads.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from ..jit import njit

#: the codec chain (zarr v3 names, in encoding order) this module decodes, with or without a
#: transpose first
LAYOUT = ("numcodecs.delta", "bytes", "numcodecs.shuffle", "zstd")
#: the transpose a store's chunks take before the delta: (y, x, azimuth) -> (azimuth, y, x), so
#: that the delta runs from each position to its neighbour at the same azimuth
TRANSPOSE = (2, 0, 1)


def skyline_codecs(block: int) -> dict:
    """The zarr codecs of a skyline array (``elevation``, ``coarse``) in chunks of ``block`` x
    ``block`` positions."""
    from zarr.codecs import Delta, Shuffle, TransposeCodec, ZstdCodec

    # numcodecs' Delta flattens its input in memory order when that is Fortran-contiguous, which a
    # transposed block of one position (1, 1, bins) is: no transpose there (nothing to predict from)
    order = [TransposeCodec(order=TRANSPOSE)] if block > 1 else []
    return {"filters": [*order, Delta(dtype="i2")],
            "compressors": [Shuffle(elementsize=2), ZstdCodec(level=9, checksum=True)]}


def chunk_reader(array):
    """A function ``(chunk coordinates, contiguous=False) -> int16 ndarray of the chunk's full
    shape`` reading ``array``'s chunks directly, or None when the array is not stored in
    :data:`LAYOUT` in a local folder (then read it through zarr). A chunk stored transposed
    comes back as a transposed view of its stored (azimuth, y, x) order, not a copy: the same
    values, the azimuth axis slowest in memory (the search gathers along azimuth rows where that
    matters); with ``contiguous``, in C order (y, x, azimuth), decoded straight into it: the
    order a block's checksum is taken over (a transposing copy afterwards cost 4-6 ms a chunk of
    64 x 64 x 360, decoding into it 1-2 ms more than into the stored order)."""
    if sys.byteorder != "little":
        return None
    try:
        meta = array.metadata.to_dict()
        root = array.store_path.store.root
        base = Path(root) / array.store_path.path
    except AttributeError:  # another zarr format, or a store that is not a folder
        return None
    codecs = list(meta.get("codecs", ()))
    transposed = bool(codecs) and codecs[0].get("name") == "transpose"
    if transposed:
        if tuple((codecs.pop(0).get("configuration") or {}).get("order", ())) != TRANSPOSE:
            return None
    if tuple(c.get("name") for c in codecs) != LAYOUT or str(meta.get("data_type")) != "int16":
        return None
    delta, byt, shuffle, _ = (c.get("configuration") or {} for c in codecs)
    if (delta.get("dtype") != "i2" or set(delta) - {"dtype"} or byt.get("endian") != "little"
            or shuffle.get("elementsize") != 2):
        return None
    grid, keys = meta.get("chunk_grid", {}), meta.get("chunk_key_encoding", {})
    if grid.get("name") != "regular" or keys.get("name") != "default":
        return None
    shape = tuple(int(v) for v in grid["configuration"]["chunk_shape"])
    if transposed and len(shape) != 3:
        return None
    from numcodecs import Zstd

    zstd = Zstd()
    key = array.metadata.encode_chunk_key

    def read(coords, contiguous: bool = False) -> np.ndarray:
        raw = zstd.decode((base / key(tuple(coords))).read_bytes())
        contiguous = contiguous and transposed
        out = np.empty((shape[2], shape[0], shape[1]) if transposed and not contiguous else shape,
                       np.int16)
        if len(raw) != 2 * out.size:
            raise ValueError(f"chunk {coords} holds {len(raw)} bytes, expected {2 * out.size}")
        if contiguous:
            unshuffle_undelta_transposed(np.frombuffer(raw, np.uint8), out.reshape(-1, shape[2]))
            return out
        unshuffle_undelta(np.frombuffer(raw, np.uint8), out.reshape(-1))
        # the stored (azimuth, y, x) order, seen as (y, x, azimuth): a view, not a copy (a
        # transposing copy cost 1.3 ms a chunk; the search reads a quarter of the positions)
        return out.transpose(1, 2, 0) if transposed else out

    return read


@njit(cache=True, nogil=True)
def unshuffle_undelta(raw, out):
    """Undo a 2-byte shuffle (all low bytes, then all high bytes) and a delta filter (int16
    cumulative sum, wrapping as numpy's does) in one pass: ``raw`` uint8 (2 n,) -> ``out`` int16 (n,)."""
    n = out.size
    s = 0
    for i in range(n):
        s = (s + (raw[i] | (raw[n + i] << 8))) & 0xFFFF
        out[i] = s - 0x10000 if s >= 0x8000 else s


@njit(cache=True, nogil=True)
def unshuffle_undelta_transposed(raw, out):
    """:func:`unshuffle_undelta` of a chunk stored (azimuth, position), written transposed:
    ``raw`` uint8 (2 n,) -> ``out`` int16 (positions, bins) C order, n = positions * bins."""
    positions, bins = out.shape
    n = out.size
    s = 0
    i = 0
    for k in range(bins):
        for p in range(positions):
            s = (s + (raw[i] | (raw[n + i] << 8))) & 0xFFFF
            out[p, k] = s - 0x10000 if s >= 0x8000 else s
            i += 1
