"""The exact path solver shared by every detector: a minimum-cost path over a column-staged graph
with in-column moves and a per-column no-skyline state (numba), and column prefix sums.

A path visits one or more pixels per column; it moves to the next column at -``window`` ..
+``window`` rows, or up/down within a column (steep or vertical skyline sections). Each column
also has an explicit *no-skyline* state; switching between it and the skyline costs
``switch_cost``. Costs are non-negative and dimensionless; :data:`BIG` forbids a state.
"""

from __future__ import annotations

import numpy as np

from ..jit import njit


BIG = 1e18


@njit(cache=True)
def solve_path(enter_cost, vert_cost, grad, none_cost, window, jump_cost, w_diff, switch_cost):
    """Exact minimum-cost path over a column-staged graph with a no-skyline state.

    enter_cost (H, W): cost of the path entering column c at row r (inf = forbidden)
    vert_cost (H, W): cost of moving onto pixel (r, c) from (r -+ 1, c) (inf = no vertical moves)
    grad (H, W): normalised gradient magnitude, for the neighbour-difference term
    none_cost (W,): cost of the no-skyline state in column c
    window: largest row change between columns; jump_cost: cost per row of change
    Returns (path_top (W,), path_bottom (W,)): the rows the path covers in each column, -1 for
    the no-skyline state.
    """
    H, W = enter_cost.shape
    D = np.empty((H, W))
    DN = np.empty(W)
    # back pointers: 0..2w = from (r + k - w, c - 1); 2w+1 = from N; 2w+2 = from above (r-1, c);
    # 2w+3 = from below (r+1, c)
    bp = np.empty((H, W), dtype=np.int16)
    bpn = np.empty(W, dtype=np.int8)  # 0: from N, 1: from the best skyline row
    best_prev_row = np.empty(W, dtype=np.int64)
    FROM_N = 2 * window + 1
    FROM_UP = 2 * window + 2
    FROM_DOWN = 2 * window + 3
    for r in range(H):
        D[r, 0] = enter_cost[r, 0]
        bp[r, 0] = FROM_N
    DN[0] = none_cost[0]
    bpn[0] = 0
    for c in range(W):
        if c > 0:
            # best skyline state of the previous column, for switches into N
            bi = 0
            bv = D[0, c - 1]
            for r in range(1, H):
                if D[r, c - 1] < bv:
                    bv = D[r, c - 1]
                    bi = r
            best_prev_row[c] = bi
            if DN[c - 1] <= bv + switch_cost:
                DN[c] = DN[c - 1] + none_cost[c]
                bpn[c] = 0
            else:
                DN[c] = bv + switch_cost + none_cost[c]
                bpn[c] = 1
            for r in range(H):
                ec = enter_cost[r, c]
                if ec >= BIG:
                    D[r, c] = BIG
                    bp[r, c] = FROM_N
                    continue
                best = DN[c - 1] + switch_cost
                arg = FROM_N
                g = grad[r, c]
                for k in range(-window, window + 1):
                    rp = r + k
                    if rp < 0 or rp >= H:
                        continue
                    v = D[rp, c - 1]
                    if v >= BIG:
                        continue
                    v += jump_cost * abs(k) + w_diff * abs(g - grad[rp, c - 1])
                    if v < best:
                        best = v
                        arg = k + window
                D[r, c] = best + ec
                bp[r, c] = arg
        # moves within the column: one sweep down, one up (costs are non-negative, so a path
        # never needs to reverse direction inside a column)
        for r in range(1, H):
            vc = vert_cost[r, c]
            if vc < BIG and D[r - 1, c] + vc < D[r, c]:
                D[r, c] = D[r - 1, c] + vc
                bp[r, c] = FROM_UP
        for r in range(H - 2, -1, -1):
            vc = vert_cost[r, c]
            if vc < BIG and D[r + 1, c] + vc < D[r, c]:
                D[r, c] = D[r + 1, c] + vc
                bp[r, c] = FROM_DOWN
    top = np.full(W, -1, dtype=np.int64)
    bottom = np.full(W, -1, dtype=np.int64)
    # end state
    bi = 0
    bv = D[0, W - 1]
    for r in range(1, H):
        if D[r, W - 1] < bv:
            bv = D[r, W - 1]
            bi = r
    in_none = DN[W - 1] <= bv
    r = bi
    c = W - 1
    while c >= 0:
        if in_none:
            if bpn[c] == 1 and c > 0:
                in_none = False
                r = best_prev_row[c]
            c -= 1
            continue
        if top[c] < 0 or r < top[c]:
            top[c] = r
        if bottom[c] < 0 or r > bottom[c]:
            bottom[c] = r
        a = bp[r, c]
        if a == FROM_UP:
            r -= 1
        elif a == FROM_DOWN:
            r += 1
        elif a == FROM_N:
            in_none = True
            c -= 1
        else:
            r = r + a - window
            c -= 1
    return top, bottom


@njit(cache=True)
def column_prefix(d, valid):
    """P[r, c] = sum of d[0:r, c] over valid pixels; shape (H + 1, W)."""
    H, W = d.shape
    P = np.zeros((H + 1, W))
    for c in range(W):
        s = 0.0
        for r in range(H):
            if valid[r, c]:
                s += d[r, c]
            P[r + 1, c] = s
    return P
