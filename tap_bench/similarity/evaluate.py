"""The TAP paper's sections 6.3 and 6.4 on the user's data.

For every trajectory (or a random sample of queries) :func:`evaluate` finds its nearest other
trajectory by ADE and by DTW on normalised shapes and counts how often that neighbour carries
a different SDL label: the paper's argument that shape distances miss behaviour (WOMD:
7,924 of 25,889 ADE neighbours and 6,246 DTW neighbours differ). It also counts the unique
labels (paper: 395) and times 1,000 comparisons of each method. As in the paper, it takes
full-length trajectories by default (valid over the whole scenario: WOMD's 9.1 s), and it
reports moving and stationary queries apart: on real data most queries are parked cars
whose nearest neighbour is another parked car at distance 0, which flatters every method.
:func:`tap_bench.similarity.figures.write_evaluation`
writes the results as JSON, a Markdown table beside the paper's figures, the per-query
neighbours, and PNG figures like the paper's Figures 5 and 6.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import pandas as pd

from tap_bench.errors import LabelTableError, ParameterError
from tap_bench.labelling import tap
from tap_bench.similarity.nearest import (
    Neighbours,
    ade_nearest,
    compile_kernels,
    dtw_nearest,
    time_comparisons,
)
from tap_bench.similarity.sdl_distance import LabelSet, label_set
from tap_bench.similarity.shape import Shapes, normalised_shapes
from tap_bench.similarity.unique import unique_labels

__all__ = ["PAPER", "SEGMENTS", "Evaluation", "evaluate", "markdown"]

SEGMENTS = ("full", "all")
"""Which trajectories :func:`evaluate` compares: ``full``, the valid segments that span
their whole scenario (the paper's 9 s WOMD tracks), or ``all`` valid segments."""
STATIONARY_TRAVEL = 1.0
"""A query whose normalised shape never gets this far [m] from its start is stationary
(SPEC section 2: it travels less than about 1 m)."""

PAPER = {
    "data": "WOMD, 492 scenarios, 25,889 vehicle trajectories of 9 s, action level",
    "trajectories": 25889,
    "ade_different": 7924,
    "ade_share": 0.3056,
    "dtw_different": 6246,
    "dtw_share": 0.2413,
    "unique": 395,
    "ms_per_1000": {"tap": 3831, "tap_labels": 3828, "tap_compare": 3, "ade": 302,
                    "dtw": 2096},
    "machine": "2.1 GHz Intel Xeon (8 cores)",
}
"""The paper's figures (sections 6.3, 6.4). Its ADE share does not match its count:
7,924 / 25,889 is 30.61 %, 30.56 % would be 7,912."""


@dataclass(frozen=True)
class Evaluation:
    """What :func:`evaluate` found.

    Attributes:
        summary: JSON-ready figures: data, counts, shares, unique labels, timings, paper.
        neighbours: one row per query: its keys and label, and for ``ade`` and ``dtw`` the
            neighbour's keys, label, distance [m] and whether the label, its lateral or its
            longitudinal part differs.
        unique: the label-table rows of the unique trajectories (most actions first).
        labels: the encoded labels of the evaluated trajectories.
        shapes: their normalised shapes, row for row.
    """

    summary: dict
    neighbours: pd.DataFrame
    unique: pd.DataFrame
    labels: LabelSet
    shapes: Shapes


def _sample(n: int, queries: int | None, seed: int) -> np.ndarray:
    if queries is None or queries >= n:
        return np.arange(n, dtype=np.int64)
    if queries < 1:
        raise ParameterError("queries", queries, "", message=f"queries must be >= 1, got {queries}")
    return np.sort(np.random.default_rng(seed).choice(n, size=queries, replace=False))


def _select(labels: pd.DataFrame, object_types: tuple[str, ...] | None) -> pd.DataFrame:
    if object_types is None or "object_type" not in labels.columns:
        return labels
    keep = labels["object_type"].astype(str).str.lower().isin(object_types).to_numpy()
    if not keep.any():
        found = sorted(set(labels["object_type"].astype(str)))
        raise LabelTableError(f"no labelled trajectory of type {', '.join(object_types)}; the "
                              f"table has {', '.join(found)}. Choose --object-types from those "
                              "(or 'all').")
    return labels.loc[keep]


def _full_length(labels: pd.DataFrame, trajectories: pd.DataFrame) -> pd.DataFrame:
    """The label rows whose segment spans its whole scenario (first to last time stamp)."""
    from tap_bench.trajectories import DT

    for col in ("t_start", "t_end"):
        if col not in labels.columns:
            raise LabelTableError(f"label table: missing column {col!r}, needed to find the "
                                  "full-length trajectories; make it with 'tap-bench label', "
                                  "or compare every segment (--segments all).")
    span = trajectories.groupby(trajectories["scenario_id"].astype(str))["t"].agg(["min", "max"])
    sid = labels["scenario_id"].astype(str)
    first = sid.map(span["min"]).to_numpy(dtype=np.float64)
    last = sid.map(span["max"]).to_numpy(dtype=np.float64)
    t0 = labels["t_start"].to_numpy(dtype=np.float64)
    t1 = labels["t_end"].to_numpy(dtype=np.float64) - DT  # t_end is exclusive
    full = (np.abs(t0 - first) < 0.5 * DT) & (np.abs(t1 - last) < 0.5 * DT)
    return labels.loc[full]


def _label_timing(trajectories: pd.DataFrame, keys: pd.DataFrame, thresholds, n: int,
                  repeats: int) -> tuple[float, int]:
    """Seconds to label ``n`` of the evaluated tracks with TAP (best of ``repeats``)."""
    tracks = keys[["scenario_id", "track_id"]].astype(str).drop_duplicates().head(n)
    key = trajectories["scenario_id"].astype(str) + "\x00" + trajectories["track_id"].astype(str)
    wanted = set(tracks["scenario_id"] + "\x00" + tracks["track_id"])
    subset = trajectories.loc[key.isin(wanted).to_numpy()]
    best = np.inf
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        tap(subset, thresholds)
        best = min(best, time.perf_counter() - t0)
    return best, len(tracks)


def _compare_timing(code: np.ndarray, pairs: int = 1_000_000, repeats: int = 3) -> float:
    """Seconds per label comparison (g_SDL on encoded labels), from a million random pairs."""
    rng = np.random.default_rng(0)
    a, b = rng.choice(code, pairs), rng.choice(code, pairs)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        np.not_equal(a, b)
        best = min(best, time.perf_counter() - t0)
    return best / pairs


def evaluate(trajectories: pd.DataFrame, labels: pd.DataFrame | None = None, *,
             level: str = "action", thresholds="paper", queries: int | None = None,
             seed: int = 0, object_types: tuple[str, ...] | None = ("vehicle",),
             ade_length: str | int = "equal", segments: str = "full",
             workers: int | None = None, timing_trajectories: int = 1000,
             progress: bool | None = None, source: str = "trajectory table") -> Evaluation:
    """Reproduce the paper's similarity (6.3) and uniqueness (6.4) experiments.

    Args:
        trajectories: the trajectory table (SPEC section 1).
        labels: its label table; labelled here with ``thresholds`` when omitted.
        level: the SDL level compared (the paper: action).
        thresholds: thresholds for labelling (and for timing TAP): preset, JSON path or
            :class:`~tap_bench.Thresholds`.
        queries: answer a random sample of this many trajectories (default: all).
        seed: seed of the sample.
        object_types: trajectories kept (the paper: vehicles); None, or a label table
            without an ``object_type`` column, keeps all.
        ade_length: ``"equal"`` or a prefix length, see :func:`ade_nearest`.
        segments: ``"full"`` (default): only trajectories valid over their whole scenario,
            the paper's full-length tracks; ``"all"``: every labelled valid segment.
        workers: threads for the nearest-neighbour searches.
        timing_trajectories: tracks labelled to time TAP.
        progress: progress bars (default: on a terminal).
        source: a name for the trajectory table in messages.
    """
    t_start = time.perf_counter()
    if labels is None:
        labels = tap(trajectories, thresholds, source=source).labels(level)
    if segments not in SEGMENTS:
        raise ParameterError("segments", segments, f"one of {', '.join(SEGMENTS)}")
    chosen = _select(label_set(labels, level).table, object_types)
    n_segments = len(chosen)
    if segments == "full":
        chosen = _full_length(chosen, trajectories)
    if len(chosen) < 2:
        hint = (f" ({len(chosen)} of {n_segments} span their whole scenario; compare every "
                "segment with segments='all', --segments all)") if segments == "full" else ""
        raise LabelTableError(f"evaluation needs at least two labelled trajectories{hint}.")
    ls = label_set(chosen, level)
    shapes = normalised_shapes(trajectories, ls.table, source=source)
    q = _sample(len(ls), queries, seed)

    # numba loads (or first compiles) its kernels here, outside the timed searches
    kernel_s = compile_kernels()
    ade = ade_nearest(shapes, q, length=ade_length, workers=workers, progress=progress)
    dtw = dtw_nearest(shapes, q, hints=ade.neighbour, workers=workers, progress=progress)

    reach = np.hypot(shapes.points[:, 0], shapes.points[:, 1])
    stationary = np.maximum.reduceat(reach, shapes.offsets[:-1]) < STATIONARY_TRAVEL

    keys = ls.table
    nb_rows, found = _neighbour_table(ls, q, stationary, (ade, dtw))

    unique_rows = np.flatnonzero(ls.counts[ls.code] == 1)
    unique = unique_labels(ls)
    label_s, n_timed = _label_timing(trajectories, keys, thresholds, timing_trajectories, 2)
    timing = _timing(shapes, ls, label_s, n_timed, ade, dtw, kernel_s)
    lengths = shapes.lengths
    summary = {
        "data": {
            "source": source, "level": ls.level, "trajectories": len(ls),
            "scenarios": int(keys["scenario_id"].nunique()),
            "object_types": list(object_types) if object_types else "all",
            "points_min": int(lengths.min()), "points_max": int(lengths.max()),
            "distinct_labels": ls.n_labels, "queries": len(q),
            "sampled": len(q) < len(ls), "seed": seed, "ade_length": ade_length,
            "segments": segments, "segments_before_selection": n_segments,
            "stationary_trajectories": int(stationary.sum()),
            "stationary_queries": int(stationary[q].sum()),
        },
        "ade": found["ade"],
        "dtw": found["dtw"],
        "sdl_exact": {
            "queries_with_exact_match": int((nb_rows["n_exact_matches"] > 0).sum()),
            "unique_labels": len(unique_rows),
            "share_unique": len(unique_rows) / len(ls),
        },
        "timing": timing,
        "paper": PAPER,
        "seconds": round(time.perf_counter() - t_start, 2),
    }
    ev = Evaluation(summary=summary, neighbours=nb_rows, unique=unique, labels=ls,
                    shapes=shapes)
    return ev


def _neighbour_table(ls: LabelSet, q: np.ndarray, stationary: np.ndarray,
                     searches: tuple[Neighbours, ...]) -> tuple[pd.DataFrame, dict[str, dict]]:
    """One row per query ``q`` (indices into the label set ``ls``): its label, its exact
    matches and, per nearest-neighbour search of ``searches`` (ADE, DTW), its neighbour, the
    distance and whether the neighbour's label differs; and per search the counts of the
    summary (moving and ``stationary`` queries apart)."""
    keys = ls.table
    lat = keys["lateral"].astype(str).to_numpy()
    lon = keys["longitudinal"].astype(str).to_numpy()
    text = ls.labels[ls.code].astype(str)
    nb_rows = pd.DataFrame({
        "query": q, "scenario_id": keys["scenario_id"].to_numpy()[q],
        "track_id": keys["track_id"].to_numpy()[q],
        "segment": keys["segment"].to_numpy()[q] if "segment" in keys.columns else 0,
        "sdl": text[q], "n_exact_matches": ls.counts[ls.code[q]] - 1,
        "stationary": stationary[q],
    })
    found: dict[str, dict] = {}
    for res in searches:
        m = res.metric
        nb = res.neighbour
        has = nb >= 0
        safe = np.where(has, nb, 0)
        nb_rows[f"{m}_neighbour"] = nb
        nb_rows[f"{m}_scenario_id"] = np.where(has, keys["scenario_id"].to_numpy()[safe], None)
        nb_rows[f"{m}_track_id"] = np.where(has, keys["track_id"].to_numpy()[safe], None)
        nb_rows[f"{m}_distance"] = res.distance
        nb_rows[f"{m}_sdl"] = np.where(has, text[safe], None)
        nb_rows[f"{m}_different"] = has & (ls.code[safe] != ls.code[q])
        nb_rows[f"{m}_lateral_different"] = has & (lat[safe] != lat[q])
        nb_rows[f"{m}_longitudinal_different"] = has & (lon[safe] != lon[q])
        answered = int(has.sum())
        diff = int(nb_rows[f"{m}_different"].sum())
        found[m] = {
            "queries_with_neighbour": answered,
            "queries_without_neighbour": int(len(q) - answered),
            "different_label": diff,
            "share_different": diff / answered if answered else None,
            "lateral_different": int(nb_rows[f"{m}_lateral_different"].sum()),
            "longitudinal_different": int(nb_rows[f"{m}_longitudinal_different"].sum()),
            "search_seconds": round(res.seconds, 4),
            "comparisons": res.comparisons,
            "distances_started": int(res.evaluated.sum()),
        }
        for part, mask in (("moving", ~stationary[q]), ("stationary", stationary[q])):
            answered_part = int((has & mask).sum())
            diff_part = int((nb_rows[f"{m}_different"].to_numpy() & mask).sum())
            found[m][part] = {
                "queries": int(mask.sum()), "queries_with_neighbour": answered_part,
                "different_label": diff_part,
                "share_different": diff_part / answered_part if answered_part else None,
                "median_distance": (float(np.median(res.distance[has & mask]))
                                    if answered_part else None),
            }
    return nb_rows, found


def _timing(shapes: Shapes, ls: LabelSet, label_s: float, n_timed: int, ade: Neighbours,
            dtw: Neighbours, kernel_s: float) -> dict[str, float | int]:
    """Milliseconds per 1000 trajectories of TAP (labelling ``n_timed`` took ``label_s``
    seconds, then comparing labels) against ADE and DTW (one comparison each, and per
    comparison in the searches), and the kernels' load time [s]."""
    per_compare = _compare_timing(ls.code)
    timing = {
        "tap_labels_ms_per_1000": round(1000 * 1000 * label_s / max(n_timed, 1), 1),
        "tap_labels_timed_on": n_timed,
        "tap_compare_ms_per_1000": round(1000 * 1000 * per_compare, 5),
        "ade_ms_per_1000": round(1000 * time_comparisons(shapes, "ade", 1000, repeats=3), 3),
        "dtw_ms_per_1000": round(1000 * time_comparisons(shapes, "dtw", 1000, repeats=3), 3),
        "ade_search_ms_per_1000": round(1e6 * ade.seconds / max(ade.comparisons, 1), 6),
        "dtw_search_ms_per_1000": round(1e6 * dtw.seconds / max(dtw.comparisons, 1), 6),
        "kernel_load_s": round(kernel_s, 2),
    }
    timing["tap_ms_per_1000"] = round(timing["tap_labels_ms_per_1000"]
                                      + timing["tap_compare_ms_per_1000"], 1)
    return timing


def _pct(x: float | None) -> str:
    return "n/a" if x is None else f"{100 * x:.2f} %"


def markdown(ev: Evaluation) -> str:
    """The results as a Markdown report beside the paper's figures."""
    s, p = ev.summary, PAPER
    d = s["data"]
    lines = [
        "# SDL similarity search against ADE and DTW (TAP paper, sections 6.3 and 6.4)",
        "",
        f"Data: `{d['source']}`: {d['trajectories']:,} trajectories "
        f"({', '.join(d['object_types']) if isinstance(d['object_types'], list) else 'all'})"
        f" in {d['scenarios']:,} scenarios, {d['points_min']}-{d['points_max']} points each; "
        f"{d['distinct_labels']:,} distinct {d['level']}-level labels; "
        + ("full-length trajectories only (valid over their whole scenario; "
           f"{d['trajectories']:,} of {d['segments_before_selection']:,} labelled segments). "
           if d["segments"] == "full" else "every labelled valid segment. ")
        + "Queries: "
        f"{d['queries']:,}" + (f" (random sample, seed {d['seed']})" if d["sampled"] else
                                " (every trajectory)") + ".",
        "",
        "## Nearest neighbour by shape, and whether it behaves the same (section 6.3)",
        "",
        "| nearest neighbour by | with a different SDL label | share | lateral differs | "
        "longitudinal differs | paper (WOMD) |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for m, label in (("ade", "ADE"), ("dtw", "DTW")):
        f = s[m]
        lines.append(
            f"| {label} | {f['different_label']:,} of {f['queries_with_neighbour']:,} | "
            f"{_pct(f['share_different'])} | {f['lateral_different']:,} | "
            f"{f['longitudinal_different']:,} | {p[m + '_different']:,} of "
            f"{p['trajectories']:,} ({100 * p[m + '_share']:.2f} %) |")
    lines += [
        "",
        f"Moving and stationary queries apart (stationary: the trajectory never gets "
        f"{STATIONARY_TRAVEL:g} m from its start; {d['stationary_queries']:,} of "
        f"{d['queries']:,} queries):",
        "",
        "| nearest neighbour by | queries | with a different SDL label | share | median "
        "distance [m] |",
        "|---|---|---:|---:|---:|",
    ]
    for m, label in (("ade", "ADE"), ("dtw", "DTW")):
        for part in ("moving", "stationary"):
            f = s[m][part]
            med = "n/a" if f["median_distance"] is None else f"{f['median_distance']:.3f}"
            lines.append(f"| {label} | {part} ({f['queries']:,}) | {f['different_label']:,} of "
                         f"{f['queries_with_neighbour']:,} | {_pct(f['share_different'])} | "
                         f"{med} |")
    no_nb = s["ade"]["queries_without_neighbour"]
    if no_nb:
        lines += ["", f"{no_nb:,} queries have no ADE neighbour: no other trajectory has their "
                  f"length (ADE length rule: {d['ade_length']})."]
    u = s["sdl_exact"]
    lines += [
        "",
        "## Unique behaviours (section 6.4)",
        "",
        "| | this data | paper (WOMD) |",
        "|---|---:|---:|",
        f"| trajectories whose label no other has | {u['unique_labels']:,} of "
        f"{d['trajectories']:,} ({_pct(u['share_unique'])}) | {p['unique']} of "
        f"{p['trajectories']:,} (1.53 %) |",
        f"| queries with at least one exact SDL match | {u['queries_with_exact_match']:,} of "
        f"{d['queries']:,} | |",
        "",
        "## Time per 1,000 comparisons",
        "",
        f"| method | this run | paper ({p['machine']}) |",
        "|---|---:|---:|",
    ]
    t, pt = s["timing"], p["ms_per_1000"]
    lines += [
        f"| TAP (label generation + comparison) | {t['tap_ms_per_1000']:,.1f} ms | "
        f"{pt['tap']:,} ms |",
        f"| TAP label generation (per 1,000 trajectories, timed on {t['tap_labels_timed_on']:,})"
        f" | {t['tap_labels_ms_per_1000']:,.1f} ms | {pt['tap_labels']:,} ms |",
        f"| TAP label comparison | {t['tap_compare_ms_per_1000']:.5f} ms | "
        f"{pt['tap_compare']} ms |",
        f"| ADE, plain compiled kernel | {t['ade_ms_per_1000']:.3f} ms | {pt['ade']} ms |",
        f"| DTW (full window), plain compiled kernel | {t['dtw_ms_per_1000']:.3f} ms | "
        f"{pt['dtw']:,} ms |",
        f"| ADE, within the pruned nearest-neighbour search | "
        f"{t['ade_search_ms_per_1000']:.6f} ms | |",
        f"| DTW, within the pruned nearest-neighbour search | "
        f"{t['dtw_search_ms_per_1000']:.6f} ms | |",
        "",
        "ADE is the mean distance between corresponding points of two normalised trajectories "
        "(start at the origin, initial heading along +x); DTW the least summed point distance "
        "over warping paths. Neighbours are exact (ties to the lowest row). The paper's ADE "
        "share (30.56 %) does not match its count (7,924 of 25,889 is 30.61 %).",
        "",
        f"Evaluated in {s['seconds']:.1f} s. Figures: `fig5_similarity.png`, "
        "`fig6_unique.png`; per-query neighbours: `neighbours.parquet`.",
    ]
    return "\n".join(lines) + "\n"
