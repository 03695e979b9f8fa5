"""SDL similarity search (TAP paper section 4.2, SPEC section 5).

Given a reference label L_ref, the search returns every labelled trajectory within ``d_sim``
of it: ``{L : g(L_ref, L) <= d_sim}``. The paper writes ``< d_sim`` but then says that
``d_sim = 0`` asks for the exact label, which only ``<=`` gives; tap-bench reads "within
d_sim" as ``<=`` throughout.

Searches work on the distinct labels of a :class:`~tap_bench.similarity.LabelSet`, never on
rows: a data set of 25,889 trajectories holds a few thousand distinct action-level labels, so
all-against-all questions (every trajectory's exact matches, every trajectory's Levenshtein
nearest neighbour) cost milliseconds to seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from tap_bench import sdl
from tap_bench.errors import LabelTableError, did_you_mean
from tap_bench.sdl import parse_sdl
from tap_bench.similarity.sdl_distance import (
    METRICS,
    LabelSet,
    label_set,
    levenshtein_matrix,
)

__all__ = [
    "ExactMatches",
    "LabelNeighbours",
    "exact_matches",
    "find_reference",
    "levenshtein_nearest",
    "search",
    "search_like",
]


def _check_metric(metric: str, d_sim: float) -> None:
    if metric not in METRICS:
        raise did_you_mean("metric", metric, METRICS)
    if not np.isfinite(d_sim) or d_sim < 0:
        raise LabelTableError(f"d_sim must be a finite distance >= 0, got {d_sim!r}.")


def _label_distances(labels: LabelSet, reference: str, metric: str) -> np.ndarray:
    """(u,) distance from ``reference`` (canonical SDL text) to each distinct label."""
    if metric == "exact":
        return (labels.labels != reference).astype(np.int32)
    return labels.levenshtein_to(reference)


def _canonical(reference: str, level: str | None, axes: tuple[str, ...]) -> str:
    parts = parse_sdl(reference, level=level, axes=axes)
    return sdl.SDL_SEPARATOR.join(sdl.join(tokens) for tokens in parts)


def search(labels: pd.DataFrame | LabelSet, reference: str, *, metric: str = "exact",
           d_sim: float = 0, level: str | None = None, axes=None) -> pd.DataFrame:
    """Every labelled trajectory whose SDL label is within ``d_sim`` of ``reference``.

    Args:
        labels: a label table (SPEC section 1) or an encoded :class:`LabelSet`.
        reference: an SDL label, e.g. ``"Straight > Left Merge > Straight | Maintain Medium
            Speed"``; separators may be spaced loosely.
        metric: ``"exact"`` (g_SDL: 0 or 1) or ``"levenshtein"`` (token edit distance).
        d_sim: the largest distance kept (``<=``); 0 keeps the exact label only.
        level: the level to search (may be omitted when the table holds one level).
        axes: the axes compared (default lateral and longitudinal; e.g. ``("lateral",
            "longitudinal", "interaction")``, whose reference is then
            ``"<lateral> | <longitudinal> | <interaction>"``).

    Returns:
        The matching rows of the label table with a ``distance`` column, nearest first (ties
        in table order).
    """
    _check_metric(metric, d_sim)
    ls = label_set(labels, level, axes=axes)
    reference = _canonical(reference, ls.level, ls.axes)
    dist = _label_distances(ls, reference, metric)
    hit = dist <= d_sim
    rows = np.flatnonzero(hit[ls.code])
    row_dist = dist[ls.code[rows]]
    order = np.argsort(row_dist, kind="stable")
    out = ls.table.take(rows[order]).reset_index(drop=True)
    out.insert(0, "distance", row_dist[order])
    return _with_label(out, ls, rows[order])


def _with_label(out: pd.DataFrame, ls: LabelSet, rows: np.ndarray) -> pd.DataFrame:
    """Beside ``sdl``, the label compared when the axes are not TAP's two (``label``)."""
    if ls.axes != sdl.AXES:
        out.insert(1, "label", ls.labels[ls.code[rows]].astype(str))
    return out


def find_reference(labels: pd.DataFrame | LabelSet, scenario_id: str, track_id: str,
                   segment: int | None = None, *, level: str | None = None, axes=None) -> int:
    """The row of one trajectory in an encoded label set.

    Raises:
        LabelTableError: no such trajectory (with close scenario ids), or a track with more
            than one labelled segment when ``segment`` is not given.
    """
    ls = label_set(labels, level, axes=axes)
    t = ls.table
    sc = t["scenario_id"].astype(str).to_numpy()
    tr = t["track_id"].astype(str).to_numpy()
    rows = np.flatnonzero((sc == str(scenario_id)) & (tr == str(track_id)))
    if len(rows) == 0:
        if str(scenario_id) not in set(sc):
            hint = did_you_mean("scenario_id", str(scenario_id), sorted(set(sc))[:10_000])
            raise LabelTableError(f"no labelled trajectory of scenario {scenario_id!r}: {hint}")
        tracks = sorted(set(tr[sc == str(scenario_id)]))
        raise LabelTableError(f"scenario {scenario_id!r} has no labelled track {track_id!r}; "
                              f"its tracks: {', '.join(tracks[:20])}"
                              f"{' ...' if len(tracks) > 20 else ''}.")
    if segment is not None:
        seg = t["segment"].to_numpy() if "segment" in t.columns else np.zeros(len(t), int)
        pick = rows[seg[rows] == int(segment)]
        if len(pick) == 0:
            raise LabelTableError(f"track {scenario_id}:{track_id} has no labelled segment "
                                  f"{segment}; it has {sorted(seg[rows].tolist())}.")
        return int(pick[0])
    if len(rows) > 1:
        segs = t["segment"].to_numpy()[rows].tolist() if "segment" in t.columns else rows.tolist()
        raise LabelTableError(
            f"track {scenario_id}:{track_id} has {len(rows)} labelled segments {segs}; pick one "
            f"as {scenario_id}:{track_id}:SEGMENT.")
    return int(rows[0])


def search_like(labels: pd.DataFrame | LabelSet, scenario_id: str, track_id: str,
                segment: int | None = None, *, metric: str = "exact", d_sim: float = 0,
                level: str | None = None, axes=None) -> pd.DataFrame:
    """Every other trajectory whose label is within ``d_sim`` of a given trajectory's label.

    As :func:`search` with the reference taken from the label table; the reference row itself
    is left out.
    """
    ls = label_set(labels, level, axes=axes)
    row = find_reference(ls, scenario_id, track_id, segment)
    _check_metric(metric, d_sim)
    reference = str(ls.labels[ls.code[row]])
    dist = _label_distances(ls, reference, metric)
    row_dist = dist[ls.code]
    rows = np.flatnonzero(row_dist <= d_sim)
    rows = rows[rows != row]
    order = np.argsort(row_dist[rows], kind="stable")
    out = ls.table.take(rows[order]).reset_index(drop=True)
    out.insert(0, "distance", row_dist[rows[order]])
    return _with_label(out, ls, rows[order])


@dataclass(frozen=True)
class ExactMatches:
    """Exact-label search for every trajectory at once (d_sim = 0, g_SDL).

    Rows are those of the :class:`LabelSet`. The matches of row ``i`` are
    ``order[offsets[code[i]]:offsets[code[i] + 1]]`` without ``i`` itself.

    Attributes:
        code: (n,) int64 distinct-label index of each row.
        order: (n,) int64 rows grouped by label, each group in row order.
        offsets: (u + 1,) int64 start of each label's group in ``order``.
        n_matches: (n,) int64 other rows with the same label (0: the label is unique).
    """

    code: np.ndarray
    order: np.ndarray
    offsets: np.ndarray
    n_matches: np.ndarray

    def matches(self, row: int) -> np.ndarray:
        """(k,) the other rows with the same label as ``row``."""
        c = self.code[row]
        group = self.order[self.offsets[c]:self.offsets[c + 1]]
        return group[group != row]


def exact_matches(labels: pd.DataFrame | LabelSet, *, level: str | None = None,
                  axes=None) -> ExactMatches:
    """Answer the exact-label search of every trajectory against all others in one pass."""
    ls = label_set(labels, level, axes=axes)
    order = np.argsort(ls.code, kind="stable")
    offsets = np.zeros(ls.n_labels + 1, dtype=np.int64)
    np.cumsum(ls.counts, out=offsets[1:])
    return ExactMatches(code=ls.code, order=order, offsets=offsets,
                        n_matches=ls.counts[ls.code] - 1)


@dataclass(frozen=True)
class LabelNeighbours:
    """The nearest other trajectory of every trajectory by a label distance.

    Attributes:
        distance: (n,) int64 distance to the nearest other row (-1 when the set has one row).
        neighbour: (n,) int64 the nearest other row; among ties, the lowest row index.
        n_at_distance: (n,) int64 other rows at exactly that distance.
    """

    distance: np.ndarray
    neighbour: np.ndarray
    n_at_distance: np.ndarray


def levenshtein_nearest(labels: pd.DataFrame | LabelSet, *, level: str | None = None,
                        chunk: int = 512, workers: int = 1, axes=None) -> LabelNeighbours:
    """Levenshtein nearest neighbour of every trajectory among all the others.

    A row whose label another row shares is at distance 0. Rows with a unique label are
    compared with every distinct label through a label-by-label distance matrix (built from
    rapidfuzz's per-axis matrices), ``chunk`` labels at a time.
    """
    ls = label_set(labels, level, axes=axes)
    n, u = len(ls), ls.n_labels
    dist = np.zeros(n, dtype=np.int64)
    neighbour = np.full(n, -1, dtype=np.int64)
    n_at = ls.counts[ls.code] - 1
    # Rows sharing their label: the nearest is the first other row of the group.
    order = np.argsort(ls.code, kind="stable")
    starts = np.zeros(u + 1, dtype=np.int64)
    np.cumsum(ls.counts, out=starts[1:])
    first = order[starts[:-1]]
    second = np.where(ls.counts > 1, order[np.minimum(starts[:-1] + 1, n - 1)], -1)
    shared = n_at > 0
    rows = np.flatnonzero(shared)
    neighbour[rows] = np.where(first[ls.code[rows]] == rows, second[ls.code[rows]],
                               first[ls.code[rows]])
    single = np.flatnonzero(ls.counts == 1)
    if u > 1 and len(single):
        for lo in range(0, len(single), chunk):
            labs = single[lo:lo + chunk]
            d = levenshtein_matrix(ls, labs, workers=workers).astype(np.int64)
            d[np.arange(len(labs)), labs] = np.iinfo(np.int64).max
            dmin = d.min(axis=1)
            at = d == dmin[:, None]
            big = np.iinfo(np.int64).max
            nb = np.where(at, ls.first_row[None, :], big).min(axis=1)
            r = ls.first_row[labs]
            dist[r] = dmin
            neighbour[r] = nb
            n_at[r] = at.astype(np.int64) @ ls.counts
    elif u == 1 and n == 1:
        dist[:] = -1
    return LabelNeighbours(distance=dist, neighbour=neighbour, n_at_distance=n_at)
