"""The sim-to-real behaviour gap: how far a policy's behaviour is from
people's, label by label.

A trajectory's behaviour is the single labels it shows on the chosen axes at one level:
its lateral manoeuvres (``Left Merge``), longitudinal ones (``Decelerate``) and, with the
interaction axis, its relations (``Following``, ``Cut-in``), each occurrence counted once.
For a policy (its egos) and a reference corpus of real driving (e.g. WOMD vehicles), the
**share** of each single label among all label occurrences is compared:

- per label: ``share_policy - share_reference`` (what the policy does more or less often
  than people), with a percentile bootstrap interval whose draws are read at Student's t
  with G - 1 degrees of freedom (G the units of the side with fewer: the draws scaled
  about the estimate by ``t_{G-1} / z``, 1.21 at 8 units, 1.07 at 20), the small-sample
  critical value of a mean over few clusters;
- one number, the **gap**: the total variation distance between the two share
  distributions, ``0.5 * sum |difference|`` in [0, 1] (the share of behaviour one would have
  to change to make the policy drive like the reference), with its bootstrap interval.

**What is resampled: scenes and episodes, each side on its own.** The vehicles of one
scene share its place, its traffic and its signals, so they are not independent draws of
real driving: the unit of independent evidence is the scene (WOMD: ``scenario_id``) and,
for rollouts, the episode (its ``scenario_id`` names env, policy and seed; a window cut
from an episode belongs to that episode). Every draw of the bootstrap takes, on each side
separately (stratified by side), as many whole units as that side has, with replacement
(:func:`tap_bench.stats.bootstrap.cluster_weights`, units named by
:func:`tap_bench.stats.bootstrap.scene_clusters`). A draw's label shares are scaled about
the estimate by ``sqrt(G / (G - 1))`` for the G units of their side
(:func:`tap_bench.stats.bootstrap.cluster_factor`), since G drawn units show only
``(G - 1) / G`` of the sampling variance. Drawing rows one by one instead makes the
intervals and the floor far too narrow, and every policy looks measurably unlike people
(docs/benchmark.md, "Intervals over scenes").

Finite samples make two draws of the same behaviour differ too, so the gap of a sample is
biased upwards (the plug-in ``gap``). The estimate to read is ``gap_debiased``, the
bootstrap bias-corrected gap ``2 gap - mean(gap*)`` (clipped at 0), with the basic
bootstrap interval ``[2 gap - q_hi, 2 gap - q_lo]`` (clipped at 0). The basic interval
alone misses a true gap of 0 (the bias is not smooth there), so its lower end is 0
whenever the gap is within what **two samples of one behaviour** show: the same draws with
each side centred on its own estimate (the difference of the two sides' sampling errors,
``0.5 * sum |(p* - p) - (r* - r)|``, the gap's distribution when the behaviours are equal,
each side with its own units and its own spread), the upper (1 + level) / 2 quantile. The
**floor** is the mean of that distribution: the gap two samples of one behaviour of these
sizes, scenes and episodes would show. Coverage and power are measured by
``benchmarks/gap_coverage.py`` (docs/benchmark.md and docs/interactions.md).

**Comparable situations.** The reference is restricted to its vehicles whose mean speed
over the trajectory lies in the policy's speed range (``min_speed`` .. ``max_speed``,
default: the 5 % and 95 % quantiles of the policy's ego mean speeds), e.g. WOMD vehicles at
highway-like speeds for a highway policy. Only a trajectory table gives speeds; a reference
label table is taken whole (and the result says so).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from tap_bench import sdl
from tap_bench.errors import FewClustersWarning, LabelTableError
from tap_bench.labelling import TapResult, tap
from tap_bench.stats.bootstrap import (
    BootstrapConfig,
    cluster_factor,
    cluster_weights,
    few_clusters_note,
    scene_clusters,
)
from tap_bench.stats.intervals import t_quantile, z_value
from tap_bench.thresholds import Thresholds

__all__ = ["GapResult", "behaviour_gap", "debias", "gap_scores", "label_occurrences",
           "labelled_with_speed"]


@dataclass(frozen=True)
class GapResult:
    """The gap of one policy from a reference.

    Attributes:
        policy: the policy's name.
        gap, gap_low, gap_high: the plug-in total variation distance of the label shares
            (biased upwards) and its percentile interval.
        floor: mean gap between two samples of the reference of the same sizes.
        gap_debiased, debiased_low, debiased_high: the bias-corrected gap and its basic
            bootstrap interval (clipped at 0): the estimate to read.
        n_policy, n_reference: trajectories compared on each side.
        n_policy_units, n_reference_units: the independent units the bootstrap drew on
            each side (episodes, scenes).
        labels: one row per single label: axis, label, share_policy, share_reference,
            diff, diff_low, diff_high; largest |diff| first.
        reference: how the reference was chosen (for reports).
    """

    policy: str
    gap: float
    gap_low: float
    gap_high: float
    floor: float
    n_policy: int
    n_reference: int
    labels: pd.DataFrame
    reference: str
    gap_debiased: float = float("nan")
    debiased_low: float = float("nan")
    debiased_high: float = float("nan")
    n_policy_units: int = 0
    n_reference_units: int = 0

    def row(self) -> dict:
        return {"policy": self.policy, "gap_debiased": self.gap_debiased,
                "debiased_low": self.debiased_low, "debiased_high": self.debiased_high,
                "gap": self.gap, "gap_low": self.gap_low,
                "gap_high": self.gap_high, "floor": self.floor, "n_policy": self.n_policy,
                "n_reference": self.n_reference, "n_policy_units": self.n_policy_units,
                "n_reference_units": self.n_reference_units, "reference": self.reference}


def labelled_with_speed(table: pd.DataFrame, level: str, *, interactions: str,
                        thresholds: str = "paper", source: str = "table") -> pd.DataFrame:
    """A label table at ``level`` with the interaction axis and a ``mean_speed`` [m/s] per
    trajectory: ``table`` labelled here when it is a trajectory table, else taken as it is
    (``mean_speed`` NaN)."""
    if "sdl" in table.columns:
        out = table[table["level"] == level] if "level" in table.columns else table
        return out.assign(mean_speed=np.nan)
    result = tap(table, thresholds, source=source, interactions=interactions)
    return result.labels(level).assign(mean_speed=_segment_mean_speed(result, source))


def _segment_mean_speed(result: TapResult, source: str) -> np.ndarray:
    """(segments,) mean speed of each labelled segment [m/s], from the speeds the labelling
    computed (``result.kinematics``: the rows it labelled, resampled to 10 Hz if need be)."""
    kin = result.kinematics
    idx = kin.index
    info = result.segments_info
    # the labelled segments are the valid segments of at least min_steps, in order
    long_enough = idx.segment_length >= result.config.min_steps
    starts = idx.segment_start[long_enough]
    stops = idx.segment_stop[long_enough]
    if len(starts) != len(info):  # pragma: no cover - internal invariant
        raise LabelTableError(f"{source}: segment layout mismatch")
    csum = np.concatenate([[0.0], np.cumsum(np.nan_to_num(kin.v))])
    return (csum[stops] - csum[starts]) / np.maximum(stops - starts, 1)


def label_occurrences(labels: pd.DataFrame, axes) -> tuple[np.ndarray, list[str]]:
    """(n, K) 0/1 matrix: which single labels (K, named ``axis: label``) each trajectory
    shows on ``axes``."""
    axes = sdl.check_axes(axes)
    names: list[str] = []
    columns = []
    for axis in axes:
        if axis not in labels.columns:
            raise LabelTableError(f"no {axis!r} column; label with --interactions for the "
                                  "interaction axis.")
        vocab = list(dict.fromkeys(t for level in sdl.LEVELS
                                   for t in sdl.vocabulary(level, axis)))
        # each distinct label text split once (a table repeats a few texts many times)
        codes, texts = pd.factorize(labels[axis].astype("string").fillna(""),
                                    use_na_sentinel=False)
        shown = np.array([[tok in seq for tok in vocab]
                          for seq in map(sdl.split, texts.astype(str))],
                         dtype=float).reshape(len(texts), len(vocab))
        names += [f"{axis}: {tok}" for tok in vocab]
        columns.append(shown[codes])
    return np.hstack(columns) if columns else np.zeros((len(labels), 0)), names


def _tv(counts_a: np.ndarray, counts_b: np.ndarray) -> np.ndarray:
    """Total variation distance between rows of two (B, K) count matrices."""
    pa = counts_a / np.maximum(counts_a.sum(axis=-1, keepdims=True), 1e-12)
    pb = counts_b / np.maximum(counts_b.sum(axis=-1, keepdims=True), 1e-12)
    return 0.5 * np.abs(pa - pb).sum(axis=-1)


def behaviour_gap(policy: pd.DataFrame, reference: pd.DataFrame, *, name: str = "policy",
                  axes=("lateral", "longitudinal", "interaction"),
                  min_speed: float | None = None, max_speed: float | None = None,
                  config: BootstrapConfig | None = None, reference_name: str = "reference",
                  clusters: str | None = "scenario_id",
                  reference_clusters: str | None = "scenario_id") -> GapResult:
    """The behaviour gap of a policy's egos from a reference corpus.

    Args:
        policy: the policy's ego labels (:func:`labelled_with_speed` rows of its egos).
        reference: the reference's labels (vehicles), with ``mean_speed`` when known.
        name: the policy's name.
        axes: the axes whose single labels are compared.
        min_speed, max_speed: [m/s] the reference's comparable speed range (default: the
            5 % and 95 % quantiles of the policy's mean speeds).
        config: bootstrap resamples, level and seed.
        reference_name: for reports.
        clusters: the column of ``policy`` naming each row's independent unit, drawn
            whole by the bootstrap (:func:`tap_bench.stats.bootstrap.scene_clusters`):
            ``scenario_id`` (default) is the episode (rollouts) or the scene (recorded
            scenes), a window's episode for windows (``<id>#<k>``); None, or a table
            without the column: each row on its own.
        reference_clusters: the same for ``reference`` (default ``scenario_id``: WOMD
            scenes).

    Warns:
        FewClustersWarning: a side has fewer than
            :data:`tap_bench.stats.bootstrap.FEW_CLUSTERS` units (its intervals are rough).
    """
    config = config or BootstrapConfig()
    axes = sdl.check_axes(axes)
    pol = policy.dropna(subset=list(axes))
    ref = reference.dropna(subset=list(axes))
    if "object_type" in ref.columns:
        ref = ref[ref["object_type"].astype(str) == "vehicle"]
    v_pol = pol["mean_speed"].to_numpy(float) if "mean_speed" in pol else np.full(len(pol),
                                                                                  np.nan)
    described = f"{reference_name}: every vehicle"
    if "mean_speed" in ref and np.isfinite(ref["mean_speed"].to_numpy(float)).any():
        lo = min_speed if min_speed is not None else (
            float(np.nanquantile(v_pol, 0.05)) if np.isfinite(v_pol).any() else 0.0)
        hi = max_speed if max_speed is not None else (
            float(np.nanquantile(v_pol, 0.95)) if np.isfinite(v_pol).any() else np.inf)
        v = ref["mean_speed"].to_numpy(float)
        ref = ref[(v >= lo) & (v <= hi)]
        described = (f"{reference_name}: vehicles with a mean speed of {lo:.1f} to {hi:.1f} "
                     "m/s (the policy's range)")
    else:
        described += " (a label table: no speeds to match situations)"
    if not len(pol) or not len(ref):
        raise LabelTableError(f"{name}: {len(pol)} policy and {len(ref)} reference "
                              f"trajectories with labels on {', '.join(axes)} in comparable "
                              "situations; nothing to compare (widen the speed range, or "
                              "label with --interactions).")
    occ_p, names = label_occurrences(pol, axes)
    occ_r, _ = label_occurrences(ref, axes)
    count_p, count_r = occ_p.sum(0), occ_r.sum(0)
    share_p = count_p / max(count_p.sum(), 1e-12)
    share_r = count_r / max(count_r.sum(), 1e-12)
    gap = float(_tv(count_p, count_r))
    units_p, units_r = scene_clusters(pol, clusters), scene_clusters(ref, reference_clusters)
    g_p, g_r = len(set(units_p)), len(set(units_r))
    note = few_clusters_note(f"gap of {name} from {reference_name}",
                             {f"policy {_unit_name(pol, clusters, 'episodes')}": g_p,
                              f"reference {_unit_name(ref, reference_clusters, 'scenes')}":
                                  g_r})
    if note:
        warnings.warn(note, FewClustersWarning, stacklevel=2)
    rng = config.rng("gap", name, reference_name)
    B = config.n_resamples
    # each side's shares in B draws of its own units (stratified by side)
    dev_p = _share_deviations(rng, occ_p, units_p, B, share_p)
    dev_r = _share_deviations(rng, occ_r, units_r, B, share_r)
    diff_boot = (share_p + dev_p) - (share_r + dev_r)
    boot_gap = 0.5 * np.abs(diff_boot).sum(axis=1)
    # two samples of one behaviour: each side's sampling error about its own estimate
    null_gap = 0.5 * np.abs(dev_p - dev_r).sum(axis=1)
    g_lo, g_hi = _percentile(boot_gap[:, None], config.level)
    same = float(np.quantile(null_gap, (1 + config.level) / 2)) if B else float("nan")
    debiased, d_low, d_high = debias(gap, boot_gap, config.level, same=same)
    # per label: a smooth statistic with few units, so the draws' spread is read at
    # Student's t with G - 1 degrees of freedom (G: the side with fewer units)
    widen = _t_over_z(min(g_p, g_r), config.level)
    diff = share_p - share_r
    d_lo, d_hi = _percentile(diff + widen * (diff_boot - diff), config.level)
    floor = float(null_gap.mean())
    shown = (count_p + count_r) > 0
    table = pd.DataFrame({
        "axis": [n.split(": ", 1)[0] for n in names], "label": [n.split(": ", 1)[1]
                                                                for n in names],
        "share_policy": share_p, "share_reference": share_r, "diff": share_p - share_r,
        "diff_low": d_lo, "diff_high": d_hi})[shown]
    table = table.reindex(table["diff"].abs().sort_values(ascending=False, kind="stable")
                          .index).reset_index(drop=True)
    return GapResult(policy=name, gap=gap, gap_low=float(g_lo[0]), gap_high=float(g_hi[0]),
                     floor=floor, n_policy=len(pol), n_reference=len(ref), labels=table,
                     reference=described, gap_debiased=debiased, debiased_low=d_low,
                     debiased_high=d_high, n_policy_units=g_p, n_reference_units=g_r)


def gap_scores(egos: pd.DataFrame, real: Mapping[str, pd.DataFrame], level: str,
               thresholds: str | Thresholds, config: BootstrapConfig
               ) -> tuple[pd.DataFrame | None, pd.DataFrame | None, dict[str, str]]:
    """The sim-to-real gap of every policy from each reference of real driving.

    Args:
        egos: the policies' egos' labels at ``level`` (env, policy, seed, ``mean_speed``
            of the episode, the label axes).
        real: reference name -> its trajectory table, labelled here at ``level`` with
            ``thresholds`` (:func:`labelled_with_speed`).
        level: the SDL level compared.
        thresholds: the TAP thresholds of the run.
        config: interval level, resamples and seed.

    Returns:
        (gap rows: reference and :meth:`GapResult.row` per policy, per-label rows:
        reference, policy and :attr:`GapResult.labels`, how they were made: table name
        -> text), the tables None when no policy had anything comparable (said in the
        ``gap skipped`` text).
    """
    axes = tuple(a for a in ("lateral", "longitudinal", "interaction") if a in egos.columns)
    methods: dict[str, str] = {}
    rows, per_label = [], []
    for name, traj in real.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            reference = labelled_with_speed(traj, level, interactions="all",
                                            thresholds=thresholds, source=name)
        for policy, mine in egos.groupby("policy", sort=True):
            try:
                gap = behaviour_gap(mine, reference, name=str(policy), axes=axes,
                                    config=config, reference_name=name)
            except LabelTableError as err:  # nothing comparable: said, not scored
                methods.setdefault("gap skipped", "")
                methods["gap skipped"] += f"{policy} vs {name}: {err} "
                continue
            rows.append({"reference": name, **gap.row()})
            per_label.append(gap.labels.assign(reference=name, policy=str(policy)))
    if not rows:
        return None, None, methods
    methods["gap"] = (
        "total variation distance between the shares of single labels ("
        + ", ".join(axes) + f") of the policy's egos and of the reference's vehicles at the "
        f"policy's speeds; {config.level:.0%} bootstrap of whole episodes of the policy and "
        f"whole scenes of the reference, each side on its own ({config.n_resamples} "
        "resamples; the debiased gap with its basic interval); floor: two samples of one "
        "behaviour with these episodes and scenes")
    return pd.DataFrame(rows), pd.concat(per_label, ignore_index=True), methods


def _t_over_z(units: int, level: float) -> float:
    """Student's t quantile with ``units - 1`` degrees of freedom over the normal one, at
    ``level`` (1.21 for 8 units, 1.07 for 20, 1.0 for many): how much wider a percentile
    interval of a mean over few clusters has to be read (NaN with fewer than 2)."""
    if units < 2:
        return float("nan")
    return t_quantile(0.5 + level / 2, units - 1) / z_value(level)


def _unit_name(table: pd.DataFrame, column: str | None, what: str) -> str:
    """What a side's units are, for messages: ``what`` (scenes, episodes) when they are
    its ``scenario_id``, the column's name for another column, ``trajectories`` when every
    row is its own."""
    if column is None or column not in table.columns:
        return "trajectories (no unit column: each its own)"
    return what if column == "scenario_id" else f"units of {column!r}"


def _share_deviations(rng: np.random.Generator, occurrences: np.ndarray, units: np.ndarray,
                      draws: int, share: np.ndarray) -> np.ndarray:
    """(draws, K) label shares of one side in bootstrap draws of whole units, less its
    estimate ``share``, scaled by :func:`tap_bench.stats.bootstrap.cluster_factor` of its
    number of units (NaN with fewer than 2 units: no spread to see)."""
    weights = cluster_weights(rng, units, draws)
    counts = weights @ occurrences
    drawn = counts / np.maximum(counts.sum(axis=1, keepdims=True), 1e-12)
    return cluster_factor(len(set(units))) * (drawn - share)


def debias(gap: float, boot: np.ndarray, level: float, *, same: float | None = None
           ) -> tuple[float, float, float]:
    """The bootstrap bias-corrected gap and its basic bootstrap interval, clipped at 0.

    Args:
        gap: the plug-in statistic.
        boot: (B,) the statistic on resampled data.
        level: the interval's level.
        same: the (1 + level) / 2 quantile of the gap between two samples of one
            behaviour (both sides pooled); a gap not above it cannot be told from 0, and
            the interval then starts at 0 (a test of "same behaviour" inverted: the
            interval holds a true gap of 0 at least (1 + level) / 2 of the time).

    Returns:
        (2 gap - mean(boot), 2 gap - q_hi, 2 gap - q_lo), each clipped at 0 (a distance).
    """
    boot = np.asarray(boot, float)
    q_lo, q_hi = np.nanquantile(boot, [(1 - level) / 2, (1 + level) / 2])
    low = max(0.0, 2 * gap - float(q_hi))
    if same is not None and gap <= same:
        low = 0.0
    return (max(0.0, 2 * gap - float(np.nanmean(boot))), low,
            max(0.0, 2 * gap - float(q_lo)))


def _percentile(boot: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    """Percentile interval of resampled statistics (B, k) along axis 0."""
    lo, hi = np.nanquantile(boot, [(1 - level) / 2, (1 + level) / 2], axis=0)
    return lo, hi
