"""Behaviour compared by interaction context: how a policy drives *when
it follows, is cut in on, or its leader brakes*.

**Occurrences** (:func:`context_occurrences`). Every run of one relation on the ego's
interaction axis (:mod:`tap_bench.interactions`, trend level: runs of at least 1 s) is an
occurrence of that context, with the measures inside its time span:

=====================  ======  ==========================================================
column                 unit    what (over the ego's steps inside the run)
=====================  ======  ==========================================================
``min_headway_s``      s       every registered measure whose entry has ``in_context``
``min_ttc_s``          s       (:attr:`~tap_bench.bench.measures.Measure.in_context`): its
``rms_jerk``           m/s^3   own function over the ego's steps inside the run, as if
                               the run were an episode (the built-ins: smallest headway
                               and TTC along the path, capped 10 s, 0 on a crash, NaN
                               with no leader inside; RMS Savitzky-Golay jerk, NaN in
                               runs shorter than its 1.5 s window). A user's measure
                               registered with ``in_context`` gets its column too
``peak_decel``         m/s^2   hardest braking: the largest deceleration (0: never slowed;
                               the impact of a crash is not braking and is left out)
``reaction_time_s``    s       Cut-in only: from the start of the Cut-in run (1 s before
                               the cutter enters the corridor) to the ego's first step
                               decelerating at or below ``a_dec``, looked for up to
                               :data:`REACTION_HORIZON_S` after; NaN when it never brakes
``braked``             share   Cut-in only: 1 when it braked within the horizon, else 0
=====================  ======  ==========================================================

**Comparison** (:func:`compare_contexts`). Per env and context, each episode's occurrences
are reduced to one value per measure by its entry's ``in_context`` (the smallest TTC and
headway, the hardest braking, the mean jerk, the first reaction), and policies A and B are
compared on the seeds where *both* meet the context: the mean paired difference A - B with
Student's t interval over those seeds (the same initial traffic, so seed noise cancels).
Where fewer than ``min_pairs`` seeds pair up, the episodes of A and of B that meet the
context are compared unpaired (Welch's t interval) and the row says so; with fewer than
``min_pairs`` episodes on a side the row has no interval. ``braked`` is a proportion: its
paired difference gets Tango's score interval, the unpaired one Newcombe's, which stay
honest when every seed braked. The intervals are :mod:`tap_bench.stats.intervals`' (a
sample whose values are all equal gets the bounded-measure interval there, or none).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
import pandas as pd

from tap_bench.bench.measures import (
    MEASURES,
    EgoSteps,
    Measure,
    ego_steps,
)
from tap_bench.errors import LabelTableError
from tap_bench.labelling import tap
from tap_bench.pathframe import LaneMap
from tap_bench.sdl import INTERACTION_NAMES
from tap_bench.stats.bootstrap import BootstrapConfig
from tap_bench.stats.intervals import paired_measure_interval, unpaired_measure_interval
from tap_bench.thresholds import Thresholds, resolve_thresholds

__all__ = ["CONTEXT_OWN_MEASURES", "REACTION_HORIZON_S", "compare_contexts",
           "context_measures", "context_occurrences", "context_scores", "occurrences_from"]

REACTION_HORIZON_S = 5.0
"""[s] how long after a cut-in starts the ego's first braking is looked for."""
CONTEXT_OWN_MEASURES: tuple[Measure, ...] = (
    # entries of what only a context has (computed by occurrences_from, no function):
    # read for unit, direction, kind, bounds and how an episode's occurrences are reduced
    Measure("peak_decel", "m/s^2", False, "hardest braking inside the context", 0.5, None,
            label="peak deceleration", in_context="max"),
    Measure("reaction_time_s", "s", False, "cut-in to the ego's first braking", 0.5, None,
            label="reaction time", in_context="first"),
    Measure("braked", "share", True, "the ego braked within the horizon of a cut-in", 0.1,
            None, label="braked", kind="rate", in_context="first"),
)
"""The measures only an interaction context has (a reaction needs the context's start)."""


def context_measures(entries: Iterable[Measure] | None = None) -> tuple[Measure, ...]:
    """The measures taken inside interaction contexts: every entry (of ``entries``, default
    the registered :data:`~tap_bench.bench.measures.MEASURES`) whose ``in_context`` says how,
    in registration order, then :data:`CONTEXT_OWN_MEASURES`. Picked by the entries' field,
    never by name: a user's measure registered with ``in_context`` is taken too."""
    entries = MEASURES if entries is None else entries
    return (*(m for m in entries if m.in_context), *CONTEXT_OWN_MEASURES)
_IDS = ("env", "policy", "seed")


def context_occurrences(trajectories: pd.DataFrame, thresholds: Thresholds | str = "paper",
                        *, source: str = "trajectory table",
                        map_table: pd.DataFrame | LaneMap | None = None) -> pd.DataFrame:
    """Every interaction context each ego meets, with the measures inside it.

    Args:
        trajectories: trajectory table with ``is_ego`` (rollouts; identifying ``env``,
            ``policy``, ``seed`` are carried).
        thresholds: TAP thresholds (``a_dec`` decides braking for the reaction time).
        source: a name for the table in error messages.
        map_table: lane centre lines along which an ego's path goes on beyond its record
            (None: an arc); one lane map of them serves both the labelling and the measures.

    Returns:
        one row per (episode, run of one relation): scenario_id, env, policy, seed (those
        present), context, other_track_id, t_start, t_end [s], and the columns of
        :func:`context_measures`.
    """
    th = resolve_thresholds(thresholds)
    if ("is_ego" not in trajectories.columns or not len(trajectories)
            or not trajectories["is_ego"].fillna(False).astype(bool).any()):
        raise LabelTableError(f"{source}: no ego (no row with is_ego true); contexts are the "
                              "interactions of each episode's ego. Give rollouts (a run's "
                              "trajectories.parquet or 'tap-bench rollout' outputs), or mark "
                              "the ego of each scenario with is_ego.")
    lanes = LaneMap.of_maps(map_table) if isinstance(map_table, pd.DataFrame) else map_table
    result = tap(trajectories, th, source=source, interactions="ego", map_table=lanes)
    return occurrences_from(result.segments("trend"), ego_steps(trajectories, lanes),
                            trajectories, th, source=source)


def occurrences_from(segments: pd.DataFrame, steps: EgoSteps, trajectories: pd.DataFrame,
                     thresholds: Thresholds, *, source: str = "trajectory table"
                     ) -> pd.DataFrame:
    """:func:`context_occurrences` from what a labelling already made: the trend-level
    segments of a ``tap(..., interactions="ego")`` call and the ego's steps
    (:func:`~tap_bench.bench.measures.ego_steps`) of the same trajectories. ``bench run``
    calls it in its workers on the tables it labels and measures anyway, so contexts cost it
    no second labelling.

    Args:
        segments: the trend-level segment table (its ``axis == "interaction"`` rows).
        steps: the ego's steps.
        trajectories: the trajectory table (its identifying columns are carried).
        thresholds: TAP thresholds (``a_dec`` decides braking).
        source: a name for the table in error messages.
    """
    th = thresholds
    runs = segments[segments["axis"] == "interaction"].reset_index(drop=True)
    episode_of = {sid: k for k, sid in enumerate(steps.scenario_id)}
    rows = []
    # per run: the ego's steps inside [t_start, t_end)
    ep = runs["scenario_id"].map(episode_of)
    if ep.isna().any():
        missing = runs.loc[ep.isna(), "scenario_id"].iloc[0]
        raise LabelTableError(f"{source}: scenario {missing!r} has interaction labels but no "
                              "ego steps.")
    ep = ep.to_numpy(np.int64)
    t = steps.t
    # the impact of a crash is no braking: acceleration from a crashed step is left out
    accel_all = steps.accel.copy()
    crashed = steps.crashed.copy()
    crashed[1:] |= steps.crashed[:-1] & steps.consecutive()
    accel_all[crashed] = np.nan
    insides = []
    # the runs' fields as lists (the values itertuples gives, without a tuple a run)
    fields = zip(*(runs[c].tolist() for c in ("scenario_id", "label", "other_track_id",
                                               "t_start", "t_end")), strict=True)
    for k, (sid, label, other, t_start, t_end) in enumerate(fields):
        lo = steps.starts[ep[k]]
        hi = lo + steps.counts[ep[k]]
        inside = np.arange(lo, hi)[(t[lo:hi] >= t_start - 1e-9) & (t[lo:hi] < t_end - 1e-9)]
        insides.append(inside)
        accel = accel_all[inside]
        row = {"scenario_id": sid, "context": label, "other_track_id": other,
               "t_start": t_start, "t_end": t_end,
               "peak_decel": float(max(0.0, -np.nanmin(accel))) if np.isfinite(accel).any()
               else np.nan,
               "reaction_time_s": np.nan, "braked": np.nan}
        if label == "Cut-in":
            later = np.arange(lo, hi)[(t[lo:hi] >= t_start - 1e-9)
                                      & (t[lo:hi] <= t_start + REACTION_HORIZON_S)]
            brake = later[accel_all[later] <= th.a_dec]
            row["braked"] = float(len(brake) > 0)
            if len(brake):
                row["reaction_time_s"] = float(t[brake[0]] - t_start)
        rows.append(row)
    measured = context_measures()
    out = pd.DataFrame(rows, columns=["scenario_id", "context", "other_track_id", "t_start",
                                      "t_end", *(m.name for m in measured)])
    # the registered measures, each by its own function over every occurrence's steps
    counts = np.array([len(i) for i in insides], np.int64)
    some = np.flatnonzero(counts > 0)
    window = _occurrence_steps(steps, [insides[k] for k in some], ep[some])
    for m in measured:
        if m.function is not None:
            values = np.full(len(out), np.nan)
            if len(some):
                values[some] = np.asarray(m.function(window), float)
            # one NaN (0 / 0 gives a negative one): the same bits as read back from the cache
            out[m.name] = np.where(np.isnan(values), np.nan, values)
    ids = [c for c in _IDS if c in trajectories.columns]
    if ids:
        out = _with_ids(out, trajectories, ids)
    return out[["scenario_id", *ids, *(c for c in out.columns
                                       if c not in ("scenario_id", *ids))]]


def _with_ids(out: pd.DataFrame, trajectories: pd.DataFrame, ids: list[str]) -> pd.DataFrame:
    """``out`` with the columns ``ids`` of the first row of its scenario in
    ``trajectories`` appended: a left merge with the table's first row of each scenario,
    taken by position where every scenario of ``out`` is there (no drop_duplicates of the
    whole trajectory table, no merge); the merge itself otherwise (its NaN, its dtypes)."""
    codes, uniques = pd.factorize(trajectories["scenario_id"])
    pos = pd.Index(uniques).get_indexer(out["scenario_id"]) if len(out) else None
    if (pos is None or (codes < 0).any() or (pos < 0).any()
            or any(c in out.columns for c in ids)):
        first = trajectories.drop_duplicates("scenario_id")[["scenario_id", *ids]]
        return out.merge(first, on="scenario_id", how="left")
    first_row = np.empty(len(uniques), np.int64)
    first_row[codes[::-1]] = np.arange(len(codes))[::-1]  # the last write is the first row
    rows = first_row[pos]
    for c in ids:
        out[c] = trajectories[c].take(rows).reset_index(drop=True)
    return out


def _occurrence_steps(steps: EgoSteps, insides: list[np.ndarray], episode: np.ndarray
                      ) -> EgoSteps:
    """The ego's steps of each occurrence (``insides``: its step indices into ``steps``, one
    or more; ``episode``: its episode), each occurrence an episode of its own: what a
    measure's function reads when it is taken inside a context."""
    idx = np.concatenate(insides) if insides else np.zeros(0, np.int64)
    counts = np.array([len(i) for i in insides], np.int64)
    step_fields = ("step", "t", "speed", "accel", "crashed", "leader_row", "gap", "closing",
                   "headway", "ttc", "scored")
    return EgoSteps(scenario_id=steps.scenario_id[episode], starts=np.cumsum(counts) - counts,
                    counts=counts, **{f: getattr(steps, f)[idx] for f in step_fields},
                    has_others=steps.has_others[episode], first_row=steps.first_row[episode],
                    columns={k: v[idx] for k, v in steps.columns.items()})


def _per_episode(occ: pd.DataFrame) -> pd.DataFrame:
    """One row per (env, policy, seed, context): each measure reduced over occurrences."""
    occ = occ.sort_values("t_start", kind="stable")
    how = {m.name: m.in_context for m in context_measures()
           if m.name in occ.columns}
    return occ.groupby(["env", "policy", "seed", "context"], sort=True).agg(how).reset_index()


def compare_contexts(occurrences: pd.DataFrame, a: str, b: str, *,
                     config: BootstrapConfig | None = None, min_pairs: int = 5,
                     contexts: tuple[str, ...] | None = None) -> pd.DataFrame:
    """Compare policies ``a`` and ``b`` inside each interaction context.

    Args:
        occurrences: :func:`context_occurrences` of both policies (with env, policy, seed).
        a, b: policy names (B is the reference: differences are A - B).
        config: the interval level.
        min_pairs: fewest seeds (or episodes per side) for an interval.
        contexts: the contexts to compare (default every relation but Free Driving).

    Returns:
        one row per env, context and measure: env, context, measure, unit,
        higher_is_better, n_pairs, n_a, n_b (episodes meeting the context), mean_a, mean_b,
        diff (A - B), diff_low, diff_high, method (``"paired by seed ..."``,
        ``"unpaired ..."`` or ``"too few"``).

    Raises:
        LabelTableError: a policy has no occurrences, or a column is missing.
    """
    config = config or BootstrapConfig()
    for col in ("env", "policy", "seed", "context"):
        if col not in occurrences.columns:
            raise LabelTableError(f"context occurrences need column {col!r}; make them with "
                                  "context_occurrences() from rollouts (env, policy, seed).")
    for name in (a, b):
        if not (occurrences["policy"] == name).any():
            known = ", ".join(map(repr, sorted(occurrences["policy"].unique())))
            raise LabelTableError(f"no context occurrences of policy {name!r}; the table has "
                                  f"{known}.")
    wanted = contexts or tuple(c for c in INTERACTION_NAMES if c != "Free Driving")
    per = _per_episode(occurrences[occurrences["policy"].isin([a, b])
                                   & occurrences["context"].isin(wanted)])
    rows = []
    for (env, context), group in per.groupby(["env", "context"], sort=True):
        side_a = group[group["policy"] == a].set_index("seed")
        side_b = group[group["policy"] == b].set_index("seed")
        seeds = side_a.index.intersection(side_b.index).sort_values()
        for m in context_measures():
            if m.name not in group.columns:
                continue
            va, vb = side_a[m.name].dropna(), side_b[m.name].dropna()
            if not len(va) and not len(vb):
                continue
            paired = [s for s in seeds if s in va.index and s in vb.index]
            row = {"env": env, "context": context, "measure": m.name, "unit": m.unit,
                   "higher_is_better": m.higher_is_better, "n_pairs": len(paired),
                   "n_a": len(va), "n_b": len(vb),
                   "mean_a": float(va.mean()) if len(va) else np.nan,
                   "mean_b": float(vb.mean()) if len(vb) else np.nan,
                   "diff": np.nan, "diff_low": np.nan, "diff_high": np.nan,
                   "method": "too few"}
            span = None if m.bounds is None else (m.bounds[0] - m.bounds[1],
                                                  m.bounds[1] - m.bounds[0])
            if len(paired) >= min_pairs:
                xa, xb = va.loc[paired].to_numpy(float), vb.loc[paired].to_numpy(float)
                lo, hi = paired_measure_interval(m, xa, xb, config.level)
                if m.is_rate:
                    method = "paired by seed (Tango score)"
                else:
                    method = ("paired by seed (t)" if np.isfinite(lo) else
                        "paired by seed (every pair differs by the same: no t interval)")
                    if span is not None and np.isfinite(lo):
                        lo, hi = max(lo, span[0]), min(hi, span[1])
                row.update(diff=float(np.mean(xa - xb)), diff_low=lo, diff_high=hi,
                           method=method, mean_a=float(xa.mean()), mean_b=float(xb.mean()))
            elif len(va) >= min_pairs and len(vb) >= min_pairs:
                lo, hi = unpaired_measure_interval(m, va.to_numpy(float), vb.to_numpy(float),
                                                   config.level)
                if m.is_rate:
                    method = "unpaired (Newcombe score)"
                else:
                    method = "unpaired (Welch t)"
                    if span is not None and np.isfinite(lo):
                        lo, hi = max(lo, span[0]), min(hi, span[1])
                row.update(diff=float(va.mean() - vb.mean()), diff_low=lo, diff_high=hi,
                           method=method)
            elif len(va) and len(vb):
                row["diff"] = float(va.mean() - vb.mean())
            rows.append(row)
    return pd.DataFrame(rows, columns=["env", "context", "measure", "unit",
                                       "higher_is_better", "n_pairs", "n_a", "n_b", "mean_a",
                                       "mean_b", "diff", "diff_low", "diff_high", "method"])


def context_scores(occurrences: pd.DataFrame, policies: Sequence[str], reference: str, *,
                   config: BootstrapConfig | None = None, min_pairs: int = 5
                   ) -> pd.DataFrame:
    """Each of ``policies`` against ``reference`` inside each interaction context: the one
    scoring of contexts ``tap-bench contexts`` (one policy) and ``bench run`` (every policy
    of the suite against its reference) share.

    Returns:
        :func:`compare_contexts`' rows with ``policy_a`` and ``policy_b`` first; empty
        (those columns) when there are no occurrences; a policy without occurrences (it
        met no context) is left out.
    """
    columns = ["policy_a", "policy_b", "env", "context", "measure", "unit",
               "higher_is_better", "n_pairs", "n_a", "n_b", "mean_a", "mean_b", "diff",
               "diff_low", "diff_high", "method"]
    if occurrences is not None and len(occurrences) and "policy" not in occurrences.columns:
        compare_contexts(occurrences, reference, reference)  # raises, naming the column
    if (occurrences is None or not len(occurrences) or
            not (occurrences["policy"] == reference).any()):
        return pd.DataFrame(columns=columns)
    tables = []
    for policy in policies:
        if policy == reference or not (occurrences["policy"] == policy).any():
            continue
        table = compare_contexts(occurrences, policy, reference, config=config,
                                 min_pairs=min_pairs)
        tables.append(table.assign(policy_a=policy, policy_b=reference))
    if not tables:
        return pd.DataFrame(columns=columns)
    return pd.concat(tables, ignore_index=True)[columns]
