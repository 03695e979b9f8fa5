"""Exact nearest neighbours by ADE and by DTW, pruned with lower bounds.

For each query trajectory the search returns the other trajectory at the smallest ADE (or
DTW) distance, ties to the lowest index, exactly as a brute-force ``argmin`` would
(:func:`brute_force_nearest` is that reference, and the tests hold the two equal). The speed
comes from never computing most distances:

- candidates are visited outward from the query along a sort key whose difference bounds
  the distance from below (ADE: the sum of x; DTW: the last point's x), so the scan stops
  as soon as the key alone exceeds the best distance found;
- cheap lower bounds discard most of the rest (ADE: centroid, then block sums; DTW: first
  and last points, then block bounding boxes, then per-point box distances);
- the survivors are computed with early abandoning (ADE: the running sum; DTW: pruned rows
  of the dynamic programme);
- serial compiled kernels (numba) run chunks of queries on a thread pool.

Lengths: DTW compares trajectories of any lengths. ADE needs equal lengths: with
``length="equal"`` (the default) a trajectory is compared with those of its own length only
(a length nobody else has gets no neighbour); with ``length=k`` every trajectory of at least
``k`` points is cut to its first ``k`` and compared with all the others, and shorter ones get
no neighbour.
"""

from __future__ import annotations

import itertools
import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import pandas as pd
from tqdm.auto import tqdm

from tap_bench.errors import ParameterError, did_you_mean
from tap_bench.similarity import kernels
from tap_bench.similarity.shape import Shapes

__all__ = [
    "SHAPE_METRICS",
    "Neighbours",
    "ade_nearest",
    "brute_force_nearest",
    "compile_kernels",
    "dtw_nearest",
    "time_comparisons",
]

SHAPE_METRICS = ("ade", "dtw")
_SMALL_GROUP = 256
"""ADE groups up to this size skip the search for exact copies."""


@dataclass(frozen=True)
class Neighbours:
    """The nearest other trajectory of each query by one shape distance.

    Attributes:
        metric: ``"ade"`` or ``"dtw"``.
        query: (q,) int64 query rows of the :class:`Shapes`.
        neighbour: (q,) int64 nearest other row, ties to the lowest row; -1 when the query
            had no candidate (ADE: no other trajectory of its length).
        distance: (q,) float64 ADE [m, mean point distance] or DTW [m, summed over the
            warping path]; NaN when there is no neighbour.
        n_candidates: (q,) int64 trajectories each query was compared against.
        evaluated: (q,) int64 candidates whose distance computation was started (the others
            were discarded by lower bounds alone).
        seconds: wall-clock time of the search [s].
    """

    metric: str
    query: np.ndarray
    neighbour: np.ndarray
    distance: np.ndarray
    n_candidates: np.ndarray
    evaluated: np.ndarray
    seconds: float

    def __len__(self) -> int:
        return len(self.query)

    @property
    def comparisons(self) -> int:
        """Query-candidate pairs the search answered (computed or pruned)."""
        return int(self.n_candidates.sum())

    def frame(self) -> pd.DataFrame:
        return pd.DataFrame({"query": self.query, "neighbour": self.neighbour,
                             "distance": self.distance, "n_candidates": self.n_candidates,
                             "evaluated": self.evaluated})


def _workers(workers: int | None) -> int:
    if workers is None:
        try:
            return max(1, len(os.sched_getaffinity(0)))
        except AttributeError:  # pragma: no cover - not Linux
            return max(1, os.cpu_count() or 1)
    if workers < 1:
        raise ParameterError("workers", workers, "", message=f"workers must be >= 1, got {workers}")
    return workers


def _queries(shapes: Shapes, queries: np.ndarray | None) -> np.ndarray:
    if queries is None:
        return np.arange(len(shapes), dtype=np.int64)
    q = np.asarray(queries, dtype=np.int64).ravel()
    if len(q) and (q.min() < 0 or q.max() >= len(shapes)):
        raise IndexError(f"query rows must lie in 0 .. {len(shapes) - 1}, got {q.min()} .. "
                         f"{q.max()}")
    return q


Task = tuple[Callable[..., None], tuple, tuple[np.ndarray, ...], tuple[np.ndarray, ...]]
"""(kernel, shared arguments, per-query arrays, per-query outputs)."""


def _run(tasks: list[Task], workers: int, chunk: int, progress: bool | None,
         desc: str) -> None:
    """Run every task's ``kernel(*args, *per_query[c], *outputs[c])`` over chunks c of its
    queries, all tasks on one thread pool and one progress bar."""
    pieces = []
    for task in tasks:
        n = len(task[2][0])
        pieces += [(task, lo, hi) for lo, hi in itertools.pairwise([*range(0, n, chunk), n])]
    total = sum(hi - lo for _, lo, hi in pieces)
    if total == 0:
        return

    def job(piece: tuple[Task, int, int]) -> int:
        (kernel, args, per_query, outputs), lo, hi = piece
        kernel(*args, *(a[lo:hi] for a in per_query), *(o[lo:hi] for o in outputs))
        return hi - lo

    with tqdm(total=total, desc=desc, unit="query", disable=None if progress is None else
              not progress, leave=False) as bar:
        if workers == 1 or len(pieces) == 1:
            for piece in pieces:
                bar.update(job(piece))
        else:
            with ThreadPoolExecutor(max_workers=workers) as pool:
                for done in pool.map(job, pieces):
                    bar.update(done)


def _duplicates(shapes: Shapes, rows: np.ndarray, L: int | None,
                summary: np.ndarray) -> np.ndarray:
    """(len(rows),) the lowest row of ``rows`` at distance 0 from each row (itself if none).

    Distance 0 means: the first L points are identical (ADE), or the sequences are equal once
    repeated consecutive points are merged (DTW, ``L`` None: such sequences warp onto each
    other at no cost). Searching one representative per group, and answering the others
    directly, keeps large groups of parked vehicles from turning the search quadratic.

    Args:
        summary: (len(rows), k) numbers that are equal for rows at distance 0 (sums, first
            and last points, bounding boxes); only rows sharing one are compared in full.
    """
    rows = np.asarray(rows, dtype=np.int64)
    rep = np.arange(len(rows))
    shared = pd.DataFrame(summary + 0.0).duplicated(keep=False).to_numpy()
    if shared.any():
        cand = np.flatnonzero(shared)
        keys = []
        for r in rows[cand]:
            a = shapes[r][:L] + 0.0  # -0.0 becomes 0.0, so bytes compare as values do
            if L is None and len(a) > 1:
                a = a[np.concatenate(([True], (a[1:] != a[:-1]).any(axis=1)))]
            keys.append(a.tobytes())
        code, _ = pd.factorize(pd.Series(keys, dtype=object))
        first = np.full(code.max() + 1, len(rows), dtype=np.int64)
        np.minimum.at(first, code, np.arange(len(cand)))
        rep[cand] = cand[first[code]]
    return rows[rep]


def _answer_duplicates(rep: np.ndarray, rows: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """For each query of ``rows``: the lowest other row with the same representative, or -1.

    Args:
        rep: (len(rows),) representative (lowest row) of each row's group.
        rows: sorted rows; queries: rows to answer.
    """
    local = np.searchsorted(rows, queries)
    group_rep = rep[local]
    # The second-lowest member of each group, for queries that are the representative.
    order = np.lexsort((rows, rep))
    srep, srow = rep[order], rows[order]
    first_pos = np.searchsorted(srep, group_rep, side="left")
    second = np.where(first_pos + 1 < len(srep), srow[np.minimum(first_pos + 1, len(srow) - 1)],
                      -1)
    second = np.where((first_pos + 1 < len(srep)) &
                      (srep[np.minimum(first_pos + 1, len(srep) - 1)] == group_rep), second, -1)
    return np.where(group_rep != queries, group_rep, second)


def _ade_groups(shapes: Shapes, length: str | int) -> tuple[list[tuple[np.ndarray, int]],
                                                            np.ndarray]:
    """[(rows, L)] groups of rows compared together on their first L points; rows left out."""
    lengths = shapes.lengths
    if isinstance(length, str):
        if length != "equal":
            raise did_you_mean("ADE length rule", length, ("equal",))
        groups = [(np.flatnonzero(lengths == L), int(L)) for L in np.unique(lengths)]
        return groups, np.zeros(0, dtype=np.int64)
    k = int(length)
    if k < 1:
        raise ParameterError("length", length, "",
            message=f"length must be 'equal' or a number of points >= 1, got {length!r}")
    return [(np.flatnonzero(lengths >= k), k)], np.flatnonzero(lengths < k)


def _dense(shapes: Shapes, rows: np.ndarray, L: int) -> np.ndarray:
    """(len(rows), L, 2) the first L points of each row."""
    idx = shapes.offsets[rows][:, None] + np.arange(L)[None, :]
    return np.ascontiguousarray(shapes.points[idx])


def ade_nearest(shapes: Shapes, queries: np.ndarray | None = None, *,
                length: str | int = "equal", blocks: int = 8, workers: int | None = None,
                chunk: int = 256, progress: bool | None = None) -> Neighbours:
    """Exact ADE nearest neighbour of each query among all other trajectories.

    Args:
        shapes: normalised trajectories (:func:`normalised_shapes`).
        queries: rows to answer (default: all).
        length: ``"equal"`` (compare equal lengths only) or a prefix length in points.
        blocks: block sums used as a lower bound (more blocks: tighter, dearer).
        workers: threads (default: the cores this process may use).
        chunk: queries per task.
        progress: show a progress bar (default: when writing to a terminal).

    Returns:
        :class:`Neighbours` with ADE distances [m].
    """
    t0 = time.perf_counter()
    q_all = _queries(shapes, queries)
    workers = _workers(workers)
    out_nb = np.full(len(q_all), -1, dtype=np.int64)
    out_d = np.full(len(q_all), np.nan)
    out_n = np.zeros(len(q_all), dtype=np.int64)
    out_ev = np.zeros(len(q_all), dtype=np.int64)
    groups, _ = _ade_groups(shapes, length)
    member = np.full(len(shapes), -1, dtype=np.int64)
    for g, (rows, _L) in enumerate(groups):
        member[rows] = g
    tasks: list[Task] = []
    finish = []
    for g, (rows, L) in enumerate(groups):
        mine = np.flatnonzero(member[q_all] == g)
        if len(mine) == 0 or len(rows) < 2:
            continue
        out_n[mine] = len(rows) - 1
        X = _dense(shapes, rows, L)
        cuts = np.unique(np.linspace(0, L, min(blocks, L) + 1).astype(np.int64))[:-1]
        S = np.add.reduceat(X, cuts, axis=1)
        cand = rows
        if len(rows) > _SMALL_GROUP:  # small groups cannot hold a costly cluster of copies
            rep = _duplicates(shapes, rows, L, np.concatenate(
                [S.reshape(len(rows), -1), X[:, -1]], axis=1))
            twin = _answer_duplicates(rep, rows, q_all[mine])
            out_nb[mine[twin >= 0]], out_d[mine[twin >= 0]] = twin[twin >= 0], 0.0
            mine = mine[twin < 0]
            keep = rep == rows  # one row per group of identical trajectories
            cand = rows[keep]
            if len(mine) == 0 or len(cand) < 2:
                continue
            X, S = X[keep], S[keep]
        X, S = np.ascontiguousarray(X), np.ascontiguousarray(S)
        C = np.ascontiguousarray(S.sum(axis=1))
        order = np.argsort(C[:, 0], kind="stable").astype(np.int64)
        pos = np.empty_like(order)
        pos[order] = np.arange(len(order))
        local = np.searchsorted(cand, q_all[mine])  # these queries are representatives
        slack = 1e-10 * L * (1.0 + float(np.abs(X).max(initial=0.0)))
        out = (np.empty(len(mine), dtype=np.int64), np.empty(len(mine)),
               np.empty(len(mine), dtype=np.int64))
        tasks.append((kernels.ade_nearest_chunk, (X, S, C, order, pos, slack), (local,), out))
        finish.append((mine, cand, L, out))
    _run(tasks, workers, chunk, progress, "ADE nearest")
    for mine, cand, L, (nb, d, ev) in finish:
        found = nb >= 0
        out_nb[mine] = np.where(found, cand[np.maximum(nb, 0)], -1)
        out_d[mine] = np.where(found, d / L, np.nan)
        out_ev[mine] = ev
    return Neighbours("ade", q_all, out_nb, out_d, out_n, out_ev, time.perf_counter() - t0)


def _dtw_features(shapes: Shapes, blocks: int) -> dict[str, np.ndarray]:
    """Per trajectory: first and last points, bounding box, and the boxes of up to ``blocks``
    consecutive non-empty blocks of points (point j of n in block (j * nb) // n, nb =
    min(blocks, n)) with their counts of interior points."""
    n = len(shapes)
    lengths = shapes.lengths
    n_blocks = np.minimum(blocks, lengths).astype(np.int64)
    # Block k of row r starts at point ceil(k * n / nb): blocks are contiguous runs of points.
    k = np.arange(blocks)[None, :]
    used = k < n_blocks[:, None]
    first_point = (shapes.offsets[:-1, None] + (k * lengths[:, None] + n_blocks[:, None] - 1)
        // n_blocks[:, None])
    starts = first_point[used]
    box = np.zeros((n, blocks, 4))
    x, y = shapes.points[:, 0], shapes.points[:, 1]
    for col, (ufunc, values) in enumerate(((np.minimum, x), (np.maximum, x), (np.minimum, y),
                                           (np.maximum, y))):
        box[:, :, col][used] = ufunc.reduceat(values, starts)
    size = np.diff(np.append(starts, len(x)))
    counts = np.zeros((n, blocks))
    counts[used] = size
    counts[:, 0] -= 1  # the first point of the trajectory
    counts[np.arange(n), n_blocks - 1] -= 1  # and its last
    whole = np.empty((n, 4))
    whole[:, 0] = np.minimum.reduceat(x, shapes.offsets[:-1])
    whole[:, 1] = np.maximum.reduceat(x, shapes.offsets[:-1])
    whole[:, 2] = np.minimum.reduceat(y, shapes.offsets[:-1])
    whole[:, 3] = np.maximum.reduceat(y, shapes.offsets[:-1])
    return {"first": np.ascontiguousarray(shapes.points[shapes.offsets[:-1]]),
            "last": np.ascontiguousarray(shapes.points[shapes.offsets[1:] - 1]),
            "box": whole, "blocks": box, "counts": counts, "n_blocks": n_blocks}


def dtw_nearest(shapes: Shapes, queries: np.ndarray | None = None, *,
                hints: np.ndarray | None = None, blocks: int = 8, workers: int | None = None,
                chunk: int = 16, progress: bool | None = None) -> Neighbours:
    """Exact DTW nearest neighbour (full window) of each query among the other trajectories.

    Args:
        shapes: normalised trajectories (:func:`normalised_shapes`); lengths may differ.
        queries: rows to answer (default: all).
        hints: (q,) a row per query to try first, e.g. its ADE neighbour (-1: none). A good
            hint tightens the bounds early; it never changes the answer.
        blocks: blocks of points per trajectory for the bounding-box lower bounds.
        workers, chunk, progress: as :func:`ade_nearest`.

    Returns:
        :class:`Neighbours` with DTW distances [m].
    """
    t0 = time.perf_counter()
    if shapes.lengths.min(initial=2) < 2:
        raise ParameterError("trajectories", "a trajectory of one point", "",
            message="every trajectory needs at least 2 points for DTW bounds")
    q_all = _queries(shapes, queries)
    workers = _workers(workers)
    hints = (np.full(len(q_all), -1, dtype=np.int64) if hints is None else
        np.asarray(hints, dtype=np.int64))
    if hints.shape != q_all.shape:
        raise ParameterError("hints", hints.shape, "",
            message=f"hints must have one row per query ({len(q_all)}), got {hints.shape}")
    n = len(shapes)
    out_nb = np.full(len(q_all), -1, dtype=np.int64)
    out_d = np.full(len(q_all), np.nan)
    out_ev = np.zeros(len(q_all), dtype=np.int64)
    rows = np.arange(n, dtype=np.int64)
    f = _dtw_features(shapes, blocks)
    rep = _duplicates(shapes, rows, None, np.concatenate([f["first"], f["last"], f["box"]],
                                                         axis=1))
    twin = _answer_duplicates(rep, rows, q_all)
    out_nb[twin >= 0], out_d[twin >= 0] = twin[twin >= 0], 0.0
    mine = np.flatnonzero(twin < 0)
    if len(mine) and n > 1:
        order = np.argsort(f["last"][:, 0], kind="stable").astype(np.int64)
        pos = np.empty_like(order)
        pos[order] = np.arange(len(order))
        candidate = rep == rows  # one row per group of trajectories at DTW distance 0
        slack = 1e-10 * int(shapes.lengths.max(initial=1)) * 2 * (
            1.0 + float(np.abs(shapes.points).max(initial=0.0)))
        nb = np.empty(len(mine), dtype=np.int64)
        d = np.empty(len(mine))
        ev = np.empty(len(mine), dtype=np.int64)
        hint = np.where(hints[mine] >= 0, rep[np.maximum(hints[mine], 0)], -1)
        _run([(kernels.dtw_nearest_chunk,
               (shapes.points, shapes.offsets, f["first"], f["last"], f["box"], f["blocks"],
                f["counts"], f["n_blocks"], order, pos, candidate, slack),
               (q_all[mine], hint), (nb, d, ev))], workers, chunk, progress, "DTW nearest")
        found = nb >= 0
        out_nb[mine] = np.where(found, nb, -1)
        out_d[mine] = np.where(found, d, np.nan)
        out_ev[mine] = ev
    return Neighbours("dtw", q_all, out_nb, out_d, np.full(len(q_all), n - 1, dtype=np.int64),
                      out_ev, time.perf_counter() - t0)


def brute_force_nearest(shapes: Shapes, queries: np.ndarray | None = None, *,
                        metric: str = "ade", length: str | int = "equal") -> Neighbours:
    """The reference: every query against every candidate in full, then ``argmin``.

    O(q * n) full distance computations; for tests and small sets only.
    """
    if metric not in SHAPE_METRICS:
        raise did_you_mean("metric", metric, SHAPE_METRICS)
    t0 = time.perf_counter()
    q_all = _queries(shapes, queries)
    n = len(shapes)
    out_nb = np.full(len(q_all), -1, dtype=np.int64)
    out_d = np.full(len(q_all), np.nan)
    out_n = np.zeros(len(q_all), dtype=np.int64)
    if metric == "ade":
        groups, _ = _ade_groups(shapes, length)
        for rows, L in groups:
            X = _dense(shapes, rows, L)
            for k, q in enumerate(q_all):
                hit = np.flatnonzero(rows == q)
                if len(hit) == 0:
                    continue
                i = int(hit[0])
                d = np.array([kernels.ade_sum(X[i], X[j]) if j != i else np.inf
                              for j in range(len(rows))])
                out_n[k] = len(rows) - 1
                if len(rows) > 1:
                    j = int(np.argmin(d))
                    out_nb[k], out_d[k] = rows[j], d[j] / L
    else:
        for k, q in enumerate(q_all):
            d = np.array([kernels.dtw_full(shapes[q], shapes[j]) if j != q else np.inf
                          for j in range(n)])
            out_n[k] = n - 1
            if n > 1:
                j = int(np.argmin(d))
                out_nb[k], out_d[k] = j, d[j]
    return Neighbours(metric, q_all, out_nb, out_d, out_n, out_n.copy(),
                      time.perf_counter() - t0)


def compile_kernels() -> float:
    """Compile (or load from numba's cache) every kernel on tiny inputs; returns seconds."""
    t0 = time.perf_counter()
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.1], [3.0, 0.0], [4.0, 0.2], [5.0, 0.0]])
    shapes = Shapes(points=np.concatenate([pts, pts * 1.1, pts * 0.9]),
                    offsets=np.array([0, 6, 12, 18]), speed=np.zeros(18), t=np.zeros(18),
                    keys=pd.DataFrame({"scenario_id": ["a", "b", "c"]}))
    ade_nearest(shapes, workers=1, progress=False)
    dtw_nearest(shapes, workers=1, progress=False)
    time_comparisons(shapes, "ade", 2)
    time_comparisons(shapes, "dtw", 2)
    return time.perf_counter() - t0


def time_comparisons(shapes: Shapes, metric: str, n: int = 1000, *, seed: int = 0,
                     repeats: int = 1) -> float:
    """Seconds for ``n`` plain (unpruned) pairwise distances between random trajectories.

    The paper's "time per 1,000 comparisons" measure; ADE pairs are drawn among trajectories
    of equal length (the most common length). Best of ``repeats``.
    """
    if metric not in SHAPE_METRICS:
        raise did_you_mean("metric", metric, SHAPE_METRICS)
    rng = np.random.default_rng(seed)
    if metric == "ade":
        lengths = shapes.lengths
        values, counts = np.unique(lengths, return_counts=True)
        pool = np.flatnonzero(lengths == values[np.argmax(counts)])
    else:
        pool = np.arange(len(shapes))
    left = rng.choice(pool, n).astype(np.int64)
    right = rng.choice(pool, n).astype(np.int64)
    out = np.empty(n)
    kind = 0 if metric == "ade" else 1
    best = np.inf
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        kernels.pairwise(kind, shapes.points, shapes.offsets, left, right, out)
        best = min(best, time.perf_counter() - t0)
    return best
