"""The sim-to-real behaviour gap (issue 14 part 3): how far a policy's behaviour is from
people's, label by label.

A trajectory's behaviour is the single labels it shows on the chosen axes at one level:
its lateral manoeuvres (``Left Merge``), longitudinal ones (``Decelerate``) and, with the
interaction axis, its relations (``Following``, ``Cut-in``), each occurrence counted once.
For a policy (its egos) and a reference corpus of real driving (e.g. WOMD vehicles), the
**share** of each single label among all label occurrences is compared:

- per label: ``share_policy - share_reference`` (what the policy does more or less often
  than people), with a percentile bootstrap interval (trajectories of each side resampled
  independently);
- one number, the **gap**: the total variation distance between the two share
  distributions, ``0.5 * sum |difference|`` in [0, 1] (the share of behaviour one would have
  to change to make the policy drive like the reference), with its bootstrap interval.

Finite samples make two draws of the same behaviour differ too, so the gap of a sample is
biased upwards; ``floor`` is the mean gap between two samples of the reference's own
distribution of the same sizes (drawn from the reference): a policy's gap is only
meaningful by how far it stands above its floor.

**Comparable situations.** The reference is restricted to its vehicles whose mean speed
over the trajectory lies in the policy's speed range (``min_speed`` .. ``max_speed``,
default: the 5 % and 95 % quantiles of the policy's ego mean speeds), e.g. WOMD vehicles at
highway-like speeds for a highway policy. Only a trajectory table gives speeds; a reference
label table is taken whole (and the result says so).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from tap_bench import sdl
from tap_bench.bench.bootstrap import BootstrapConfig
from tap_bench.errors import LabelTableError
from tap_bench.kinematics import compute_kinematics
from tap_bench.labelling import tap
from tap_bench.trajectories import validate_and_index

__all__ = ["GapResult", "behaviour_gap", "label_occurrences", "labelled_with_speed"]


@dataclass(frozen=True)
class GapResult:
    """The gap of one policy from a reference.

    Attributes:
        policy: the policy's name.
        gap, gap_low, gap_high: total variation distance of the label shares, interval.
        floor: mean gap between two samples of the reference of the same sizes.
        n_policy, n_reference: trajectories compared on each side.
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

    def row(self) -> dict:
        return {"policy": self.policy, "gap": self.gap, "gap_low": self.gap_low,
                "gap_high": self.gap_high, "floor": self.floor, "n_policy": self.n_policy,
                "n_reference": self.n_reference, "reference": self.reference}


def labelled_with_speed(table: pd.DataFrame, level: str, *, interactions: str,
                        thresholds: str = "paper", source: str = "table") -> pd.DataFrame:
    """A label table at ``level`` with the interaction axis and a ``mean_speed`` [m/s] per
    trajectory: ``table`` labelled here when it is a trajectory table, else taken as it is
    (``mean_speed`` NaN)."""
    if "sdl" in table.columns:
        out = table[table["level"] == level] if "level" in table.columns else table
        return out.assign(mean_speed=np.nan)
    result = tap(table, thresholds, source=source, interactions=interactions)
    return result.labels(level).assign(mean_speed=_segment_mean_speed(result, table, source))


def _segment_mean_speed(result, table: pd.DataFrame, source: str) -> np.ndarray:
    """(segments,) mean speed of each labelled segment [m/s]."""
    kin = compute_kinematics(validate_and_index(table, source=source))
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
        tokens = labels[axis].astype("string").fillna("").map(sdl.split)
        for tok in dict.fromkeys(t for level in sdl.LEVELS
                                 for t in sdl.vocabulary(level, axis)):
            names.append(f"{axis}: {tok}")
            columns.append(tokens.map(lambda seq, tok=tok: tok in seq).to_numpy(float))
    return np.column_stack(columns) if columns else np.zeros((len(labels), 0)), names


def _tv(counts_a: np.ndarray, counts_b: np.ndarray) -> np.ndarray:
    """Total variation distance between rows of two (B, K) count matrices."""
    pa = counts_a / np.maximum(counts_a.sum(axis=-1, keepdims=True), 1e-12)
    pb = counts_b / np.maximum(counts_b.sum(axis=-1, keepdims=True), 1e-12)
    return 0.5 * np.abs(pa - pb).sum(axis=-1)


def behaviour_gap(policy: pd.DataFrame, reference: pd.DataFrame, *, name: str = "policy",
                  axes=("lateral", "longitudinal", "interaction"),
                  min_speed: float | None = None, max_speed: float | None = None,
                  config: BootstrapConfig | None = None, reference_name: str = "reference"
                  ) -> GapResult:
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
    rng = config.rng("gap", name, reference_name)
    B = config.n_resamples
    # resampled label counts: multinomial draws of trajectories on each side
    wp = rng.multinomial(len(occ_p), np.full(len(occ_p), 1 / len(occ_p)), size=B)
    wr = rng.multinomial(len(occ_r), np.full(len(occ_r), 1 / len(occ_r)), size=B)
    bp, br = wp @ occ_p, wr @ occ_r
    boot_gap = _tv(bp, br)
    g_lo, g_hi = _percentile(boot_gap[:, None], config.level)
    diff_boot = (bp / np.maximum(bp.sum(1, keepdims=True), 1e-12)
                 - br / np.maximum(br.sum(1, keepdims=True), 1e-12))
    d_lo, d_hi = _percentile(diff_boot, config.level)
    # the floor: two samples of the reference's own label distribution, of the same sizes
    w1 = rng.multinomial(len(occ_p), np.full(len(occ_r), 1 / len(occ_r)), size=B)
    w2 = rng.multinomial(len(occ_r), np.full(len(occ_r), 1 / len(occ_r)), size=B)
    floor = float(_tv(w1 @ occ_r, w2 @ occ_r).mean())
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
                     reference=described)


def _percentile(boot: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    """Percentile interval of resampled statistics (B, k) along axis 0."""
    lo, hi = np.nanquantile(boot, [(1 - level) / 2, (1 + level) / 2], axis=0)
    return lo, hi
