"""Compiled kernels for ADE and DTW: pairwise distances and pruned exact nearest neighbours.

numba compiles these on first use and caches the machine code beside this file
(``cache=True``), so the compile time (a few seconds) is paid once per installation; see
:func:`tap_bench.similarity.nearest.compile_kernels`. Every kernel is serial and releases
the GIL (``nogil=True``): the callers run chunks of queries on a thread pool instead of
numba's parallel layer, whose worker threads spin while they wait and crawl on a shared
machine.

Conventions: a trajectory is an (n, 2) block of float64 points; the point cost is the
Euclidean distance sqrt(dx^2 + dy^2), computed by the same expression everywhere so that
pruned and brute-force searches produce bit-identical distances. Searches return sums (ADE
is the sum divided by the length) and break ties by the lowest candidate index, as
``argmin`` over a brute-force distance row does.

Pruning never changes a result: a candidate is skipped only when a lower bound of its
distance exceeds ``best * (1 + REL) + slack``, where ``slack`` absorbs the rounding of the
bounds (the caller sets it from the data's scale).
"""

from __future__ import annotations

import numpy as np
from numba import njit

REL = 1e-9
"""Relative slack on every pruning bound (the bounds round differently from the distance)."""


@njit(cache=True, nogil=True)
def _cost(a, i, b, j):
    dx = a[i, 0] - b[j, 0]
    dy = a[i, 1] - b[j, 1]
    return np.sqrt(dx * dx + dy * dy)


@njit(cache=True, nogil=True)
def ade_sum(a, b):
    """Sum over t of ||a_t - b_t|| for (n, 2) arrays of equal n [m]."""
    s = 0.0
    for t in range(a.shape[0]):
        s += _cost(a, t, b, t)
    return s


@njit(cache=True, nogil=True)
def dtw_full(a, b):
    """DTW distance of (n, 2) and (m, 2): min over warping paths of the summed point costs.

    Full window, steps (1, 0), (0, 1), (1, 1); two rows of the dynamic programme.
    """
    n, m = a.shape[0], b.shape[0]
    prev = np.empty(m)
    curr = np.empty(m)
    s = 0.0
    for j in range(m):
        s += _cost(a, 0, b, j)
        prev[j] = s
    for i in range(1, n):
        curr[0] = _cost(a, i, b, 0) + prev[0]
        for j in range(1, m):
            v = prev[j - 1]
            if prev[j] < v:
                v = prev[j]
            if curr[j - 1] < v:
                v = curr[j - 1]
            curr[j] = _cost(a, i, b, j) + v
        prev, curr = curr, prev
    return prev[m - 1]


@njit(cache=True, nogil=True)
def pairwise(kind, points, offsets, left, right, out):
    """out[k] = distance(left[k], right[k]) for ragged trajectories (kind 0 ADE sum, 1 DTW)."""
    for k in range(left.shape[0]):
        a = points[offsets[left[k]]:offsets[left[k] + 1]]
        b = points[offsets[right[k]]:offsets[right[k] + 1]]
        if kind == 0:
            out[k] = ade_sum(a, b)
        else:
            out[k] = dtw_full(a, b)


@njit(cache=True, nogil=True)
def _keep_nearer(d, c, best, best_j):
    """(best, best_j) after candidate c at distance d: nearer wins, ties to the lower row."""
    if d < best or (d == best and c < best_j):
        return d, c
    return best, best_j


@njit(cache=True, nogil=True)
def _outward(key, order, kq, left, right):
    """The next candidate outward from a query along a sorted key.

    ``order`` sorts the rows by ``key``; ``left`` and ``right`` are the next positions on
    either side of the query's. Returns (row, |key difference|, left, right) for the side
    whose next key is nearer ``kq``; row -1 once both sides are exhausted.
    """
    dl = kq - key[order[left]] if left >= 0 else np.inf
    dr = key[order[right]] - kq if right < order.shape[0] else np.inf
    if dl <= dr:
        if dl == np.inf:
            return -1, np.inf, left, right
        return order[left], dl, left - 1, right
    return order[right], dr, left, right + 1


# -- ADE: exact nearest neighbours among trajectories of one length --------------------------
@njit(cache=True, nogil=True)
def ade_nearest_chunk(X, S, C, order, pos, slack, queries, out_nb, out_sum, out_eval):
    """ADE nearest neighbour of each query among all rows of X (itself excluded).

    Args:
        X: (N, L, 2) normalised trajectories of one length.
        S: (N, K, 2) sums of the points of K consecutive blocks of each trajectory.
        C: (N, 2) sums of all points.
        order: (N,) rows sorted by C[:, 0]; pos: (N,) position of each row in ``order``.
        slack: absolute slack on the bounds [m, in sum units].
        queries: (q,) rows to answer.
        out_nb, out_sum, out_eval: (q,) neighbour row, its ADE sum, candidates evaluated in
            full or abandoned early.

    Bounds (in sum units, all <= sum_t ||a_t - b_t||): |sum of x differences| (the scan
    order), ||C_a - C_b||, and sum_k ||S_a,k - S_b,k|| (each block's points: the norm of a sum
    is at most the sum of norms). Candidates are visited outward from the query in the
    sorted order, nearest key first, until the key difference alone exceeds the best sum.
    """
    length = X.shape[1]
    n_blocks = S.shape[1]
    key = C[:, 0]
    for qi in range(queries.shape[0]):
        q = queries[qi]
        xq = X[q]
        p = pos[q]
        kq = C[q, 0]
        best = np.inf
        best_j = -1
        evaluated = 0
        left = p - 1
        right = p + 1
        while True:
            c, dk, left, right = _outward(key, order, kq, left, right)
            if c < 0:
                break
            bound = best * (1.0 + REL) + slack
            if dk > bound:
                break
            dx = C[q, 0] - C[c, 0]
            dy = C[q, 1] - C[c, 1]
            if np.sqrt(dx * dx + dy * dy) > bound:
                continue
            lb = 0.0
            for k in range(n_blocks):
                dx = S[q, k, 0] - S[c, k, 0]
                dy = S[q, k, 1] - S[c, k, 1]
                lb += np.sqrt(dx * dx + dy * dy)
                if lb > bound:
                    break
            if lb > bound:
                continue
            evaluated += 1
            xc = X[c]
            s = 0.0
            for t in range(length):
                s += _cost(xq, t, xc, t)
                if s > bound:
                    break
            if s <= bound:
                best, best_j = _keep_nearer(s, c, best, best_j)
        out_nb[qi] = best_j
        out_sum[qi] = best
        out_eval[qi] = evaluated


# -- DTW: exact nearest neighbours among ragged trajectories ---------------------------------
@njit(cache=True, nogil=True)
def _box_distance(ax0, ax1, ay0, ay1, bx0, bx1, by0, by1):
    dx = max(0.0, ax0 - bx1, bx0 - ax1)
    dy = max(0.0, ay0 - by1, by0 - ay1)
    if dx == 0.0 or dy == 0.0:  # overlapping on an axis: no square root needed
        return dx + dy
    return np.sqrt(dx * dx + dy * dy)


@njit(cache=True, nogil=True)
def _point_box_distance(a, i, boxes, k):
    """Distance from point a[i] to the box boxes[k] = (xmin, xmax, ymin, ymax)."""
    dx = max(0.0, boxes[k, 0] - a[i, 0], a[i, 0] - boxes[k, 1])
    dy = max(0.0, boxes[k, 2] - a[i, 1], a[i, 1] - boxes[k, 3])
    if dx == 0.0 or dy == 0.0:
        return dx + dy
    return np.sqrt(dx * dx + dy * dy)


@njit(cache=True, nogil=True)
def _blocks_bound(blocks, counts, n_blocks, r, box):
    """sum_k counts[r, k] * distance(block box k of row r, box): rows r's interior points."""
    lb = 0.0
    for k in range(n_blocks[r]):
        if counts[r, k] > 0:
            lb += counts[r, k] * _box_distance(blocks[r, k, 0], blocks[r, k, 1],
                                               blocks[r, k, 2], blocks[r, k, 3],
                                               box[0], box[1], box[2], box[3])
    return lb


@njit(cache=True, nogil=True)
def _points_bound(a, boxes, k, limit):
    """sum over a's interior points of their distance to boxes[k]; stops once past limit."""
    lb = 0.0
    for i in range(1, a.shape[0] - 1):
        lb += _point_box_distance(a, i, boxes, k)
        if lb > limit:
            break
    return lb


@njit(cache=True, nogil=True)
def dtw_bounded(a, b, rest, bound, prev, curr):
    """DTW of a (n, 2) and b (m, 2), or inf once it must exceed ``bound``.

    ``rest[i]`` bounds from below the cost of any warping path's cells in rows i .. n-1
    (``rest[n] = 0``). A cell is dead when its cost so far plus ``rest`` of the rows below
    exceeds ``bound``; each row is computed only from the first live column of the row above
    to the last live one, and on while cells stay live (the PrunedDTW scheme of Silva and
    Batista, with the row bound of the UCR suite). A value returned at most ``bound`` is
    bit-identical to :func:`dtw_full`: a live cell's cheapest predecessor is live.
    """
    n, m = a.shape[0], b.shape[0]
    s = 0.0
    psc = 0
    pec = -1
    limit = bound - rest[1]
    for j in range(m):
        s += _cost(a, 0, b, j)
        if s > limit:
            break
        prev[j] = s
        pec = j
    if pec < 0:
        return np.inf
    for i in range(1, n):
        limit = bound - rest[i + 1]
        nsc = -1
        nec = -1
        left = np.inf
        ax = a[i, 0]
        ay = a[i, 1]
        j = psc
        while j < m:
            v = left
            if j <= pec and prev[j] < v:
                v = prev[j]
            if j - 1 >= psc and j - 1 <= pec and prev[j - 1] < v:
                v = prev[j - 1]
            if v == np.inf:
                if j > pec:
                    break
                curr[j] = np.inf
                left = np.inf
            else:
                dx = ax - b[j, 0]
                dy = ay - b[j, 1]
                d = np.sqrt(dx * dx + dy * dy) + v  # _cost(a, i, b, j), bit for bit
                if d > limit:
                    curr[j] = np.inf
                    left = np.inf
                    if j > pec:
                        break
                else:
                    curr[j] = d
                    left = d
                    if nsc < 0:
                        nsc = j
                    nec = j
            j += 1
        if nsc < 0:
            return np.inf
        prev, curr = curr, prev
        psc = nsc
        pec = nec
    if pec == m - 1:
        return prev[m - 1]
    return np.inf


@njit(cache=True, nogil=True)
def dtw_nearest_chunk(P, off, first, last, box, blocks, counts, n_blocks, order, pos,
                      candidate, slack, queries, hints, out_nb, out_sum, out_eval):
    """DTW nearest neighbour of each query among the candidate rows (itself excluded).

    Args:
        P: (total, 2) points of all trajectories laid end to end; off: (N + 1,) offsets.
        first, last: (N, 2) first and last points; box: (N, 4) bounding boxes
            (xmin, xmax, ymin, ymax).
        blocks: (N, K, 4) boxes of consecutive blocks of points (row r uses the first
            n_blocks[r] <= K, none empty); counts: (N, K) points of each block other than
            the first and last of the trajectory; n_blocks: (N,) int64.
        order: (N,) rows sorted by last[:, 0]; pos: (N,) position of each row in it.
        candidate: (N,) bool, rows that may be returned.
        slack: absolute slack on the bounds [m].
        queries: (q,) rows to answer; hints: (q,) a row to try first (-1 for none).
        out_nb, out_sum, out_eval: (q,) neighbour row, its DTW distance, candidates whose
            dynamic programme was started.

    Bounds, each at most the DTW distance, cheapest first: the first and last cells of every
    path (||first_a - first_b|| + ||last_a - last_b||, at least the difference of the last
    x, which orders the scan); every interior row and column holds a cell, which costs at
    least its point's distance to the other's bounding box: per block of points, then per
    point (columns, then rows, whose suffix sums then prune the dynamic programme). A
    row-by-block chain bound (a coarse DTW over blocks of columns) was tried as well: it is
    tighter, but costs more than the programmes it saves on trajectory data.
    """
    n_rows = order.shape[0]
    key = last[:, 0]
    max_len = 0
    for r in range(n_rows):
        if off[r + 1] - off[r] > max_len:
            max_len = off[r + 1] - off[r]
    prev = np.empty(max_len)
    curr = np.empty(max_len)
    rest = np.empty(max_len + 1)
    for qi in range(queries.shape[0]):
        q = queries[qi]
        a = P[off[q]:off[q + 1]]
        p = pos[q]
        kq = last[q, 0]
        best = np.inf
        best_j = -1
        evaluated = 0
        left = p - 1
        right = p + 1
        hint = hints[qi]
        while True:
            if hint >= 0:
                c = hint
                hint = -1
                dk = 0.0
            else:
                c, dk, left, right = _outward(key, order, kq, left, right)
                if c < 0:
                    break
            bound = best * (1.0 + REL) + slack
            if dk > bound:
                break
            if c == q or not candidate[c] or c == best_j:
                continue
            dx = first[q, 0] - first[c, 0]
            dy = first[q, 1] - first[c, 1]
            ends = np.sqrt(dx * dx + dy * dy)
            dx = last[q, 0] - last[c, 0]
            dy = last[q, 1] - last[c, 1]
            ends += np.sqrt(dx * dx + dy * dy)
            if ends > bound:
                continue
            if ends + _blocks_bound(blocks, counts, n_blocks, q, box[c]) > bound:
                continue
            if ends + _blocks_bound(blocks, counts, n_blocks, c, box[q]) > bound:
                continue
            b = P[off[c]:off[c + 1]]
            if ends + _points_bound(b, box, q, bound - ends) > bound:
                continue
            # rest[i]: the cells of rows i .. n-1: each interior row's point to c's box, and
            # the last cell. Built from the end: every partial sum is already a bound.
            n, m = a.shape[0], b.shape[0]
            rest[n] = 0.0
            rest[n - 1] = _cost(a, n - 1, b, m - 1)
            first_cell = _cost(a, 0, b, 0)
            pruned = False
            for i in range(n - 2, 0, -1):
                rest[i] = rest[i + 1] + _point_box_distance(a, i, box, c)
                if first_cell + rest[i] > bound:
                    pruned = True
                    break
            if pruned:
                continue
            evaluated += 1
            d = dtw_bounded(a, b, rest, bound, prev, curr)
            if d <= bound:
                best, best_j = _keep_nearer(d, c, best, best_j)
        out_nb[qi] = best_j
        out_sum[qi] = best
        out_eval[qi] = evaluated
