"""The realism score: likelihood of the logged features under the simulated ones (SPEC 9).

The estimator and weights are WOSAC 2025's (the challenge's ``challenge_2025_sim_agents``
configuration), written here from its published definition:

- a **histogram** feature (speeds, accelerations, distances, time to collision): per agent,
  the K x T simulated values (every rollout, every valid step) fill a histogram of fixed
  bins (:data:`WOSAC_2025`), each bin count plus a pseudocount of 0.1, normalised; each
  logged value (clipped to the bins' range) gets the log-probability of its bin; the
  feature's likelihood is exp(mean log-probability over the valid logged steps);
- a **Bernoulli** feature (collision, off-road, traffic-light violation): per agent, whether
  it happened at any valid step, in each rollout (the K outcomes, pseudocount 0.001) and in
  the log; the likelihood is exp(mean log-probability over agents);
- the **meta-metric**: the weighted sum of the ten likelihoods (weights sum to 1).

A scene's likelihood of a feature pools the log-probabilities of its agents (and steps)
before the exponential, as WOSAC does; a group of agents (an object type, a manoeuvre) pools
its own agents the same way. Scores are averaged over scenes.

Data contract: :func:`agent_log_likelihoods` takes per feature the logged values (n, T) and
the simulated ones (K, n, T) with NaN where undefined (Bernoulli features as (n,) and (K, n)
bools), and returns a table with one row per agent and feature: the sum of log-probabilities
and the number of terms, from which :func:`pooled` forms likelihoods for any group.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pandas as pd

from tap_bench.errors import ParameterError

__all__ = ["BERNOULLI_FEATURES", "FEATURES", "HISTOGRAM_FEATURES", "WOSAC_2025", "FeatureSpec",
           "agent_log_likelihoods", "bernoulli_log_prob", "histogram_log_prob",
           "meta_metric", "pooled"]


@dataclass(frozen=True)
class FeatureSpec:
    """How one feature is scored.

    Attributes:
        weight: its weight in the meta-metric.
        low, high: the histogram's range (values outside are clipped to it).
        bins: number of equal bins (0: a Bernoulli feature).
        pseudocount: added to every bin's count.
    """

    weight: float
    low: float = 0.0
    high: float = 1.0
    bins: int = 0
    pseudocount: float = 0.001

    def __post_init__(self) -> None:
        if not 0 <= self.weight <= 1:
            raise ParameterError("weight", self.weight, "a number from 0 to 1")
        if self.bins < 0 or (self.bins and not self.high > self.low):
            raise ParameterError("bins", (self.bins, self.low, self.high),
                                 "0 (Bernoulli), or bins > 0 with high > low")
        if self.pseudocount <= 0:
            raise ParameterError("pseudocount", self.pseudocount, "a positive count")


WOSAC_2025: dict[str, FeatureSpec] = {
    "linear_speed": FeatureSpec(0.05, 0.0, 25.0, 10, 0.1),
    "linear_acceleration": FeatureSpec(0.05, -12.0, 12.0, 11, 0.1),
    "angular_speed": FeatureSpec(0.05, -0.628, 0.628, 11, 0.1),
    "angular_acceleration": FeatureSpec(0.05, -3.14, 3.14, 11, 0.1),
    "distance_to_nearest_object": FeatureSpec(0.1, -5.0, 40.0, 10, 0.1),
    "collision_indication": FeatureSpec(0.25),
    "time_to_collision": FeatureSpec(0.1, 0.0, 5.0, 10, 0.1),
    "distance_to_road_edge": FeatureSpec(0.05, -20.0, 40.0, 10, 0.1),
    "offroad_indication": FeatureSpec(0.25),
    "traffic_light_violation": FeatureSpec(0.05),
}
"""WOSAC 2025's features, histogram ranges, bins, pseudocounts and meta-metric weights."""

FEATURES = tuple(WOSAC_2025)
HISTOGRAM_FEATURES = tuple(f for f in FEATURES if WOSAC_2025[f].bins)
BERNOULLI_FEATURES = tuple(f for f in FEATURES if not WOSAC_2025[f].bins)


def _bin(values: np.ndarray, spec: FeatureSpec) -> np.ndarray:
    """The bin of each value (clipped to the range; the top edge is in the last bin)."""
    v = np.clip(values, spec.low, spec.high)
    k = np.floor((v - spec.low) / (spec.high - spec.low) * spec.bins).astype(np.int64)
    return np.minimum(k, spec.bins - 1)


def histogram_log_prob(logged: np.ndarray, simulated: np.ndarray, spec: FeatureSpec
                       ) -> np.ndarray:
    """Log-probability of each logged value under its agent's simulated histogram.

    Args:
        logged: (n, T) values, NaN where not scored.
        simulated: (n, S) the agent's simulated samples (K x T pooled), NaN ignored.
        spec: the bins.

    Returns:
        (n, T), NaN where ``logged`` is NaN.
    """
    n = logged.shape[0]
    counts = np.full((n, spec.bins), spec.pseudocount)
    rows, cols = np.nonzero(np.isfinite(simulated))
    np.add.at(counts, (rows, _bin(simulated[rows, cols], spec)), 1.0)
    logp = np.log(counts / counts.sum(axis=1, keepdims=True))
    out = np.full(logged.shape, np.nan)
    ok = np.isfinite(logged)
    r, c = np.nonzero(ok)
    out[r, c] = logp[r, _bin(logged[r, c], spec)]
    return out


def bernoulli_log_prob(logged: np.ndarray, simulated: np.ndarray, spec: FeatureSpec
                       ) -> np.ndarray:
    """Log-probability of each agent's logged outcome under its K simulated outcomes.

    Args:
        logged: (n,) bool.
        simulated: (K, n) bool.

    Returns:
        (n,)
    """
    k = simulated.shape[0]
    hits = simulated.sum(axis=0)
    p_true = (hits + spec.pseudocount) / (k + 2 * spec.pseudocount)
    return np.log(np.where(logged, p_true, 1.0 - p_true))


def agent_log_likelihoods(logged: Mapping[str, np.ndarray], simulated: Mapping[str, np.ndarray],
                          specs: Mapping[str, FeatureSpec] = WOSAC_2025) -> pd.DataFrame:
    """Per agent and feature: the sum of log-probabilities and the number of terms.

    Args:
        logged: feature -> (n, T) logged values (NaN: step not scored), or (n,) bool for a
            Bernoulli feature (None/absent rows: use a float array with NaN to leave an agent
            out).
        simulated: feature -> (K, n, T) simulated values (NaN: undefined), or (K, n) bool.
        specs: the features to score.

    Returns:
        Columns ``agent`` (row index), ``feature``, ``log_prob_sum``, ``terms``.
    """
    frames = []
    for name, spec in specs.items():
        log_v = np.asarray(logged[name])
        sim_v = np.asarray(simulated[name])
        if spec.bins:
            k, n, t = sim_v.shape
            pooled_sim = np.transpose(sim_v, (1, 0, 2)).reshape(n, k * t)
            lp = histogram_log_prob(log_v.astype(float), pooled_sim.astype(float), spec)
            ok = np.isfinite(lp)
            sums = np.where(ok, lp, 0.0).sum(axis=1)
            terms = ok.sum(axis=1)
        else:
            scored = np.ones(log_v.shape, bool)
            if log_v.dtype.kind == "f":
                scored = np.isfinite(log_v)
            lp = bernoulli_log_prob(np.nan_to_num(log_v).astype(bool), sim_v.astype(bool), spec)
            sums = np.where(scored, lp, 0.0)
            terms = scored.astype(np.int64)
        frames.append(pd.DataFrame({"agent": np.arange(len(sums)), "feature": name,
                                    "log_prob_sum": sums, "terms": terms}))
    return pd.concat(frames, ignore_index=True)


def pooled(table: pd.DataFrame, specs: Mapping[str, FeatureSpec] = WOSAC_2025
           ) -> dict[str, float]:
    """Each feature's likelihood over the agents of ``table`` (rows of
    :func:`agent_log_likelihoods`): exp(sum of log-probabilities / terms); NaN with no
    term. Adds ``meta_metric`` (:func:`meta_metric`)."""
    sums = table.groupby("feature", sort=False)[["log_prob_sum", "terms"]].sum()
    out = {}
    for name in specs:
        if name in sums.index and sums.loc[name, "terms"] > 0:
            out[name] = float(np.exp(sums.loc[name, "log_prob_sum"] / sums.loc[name, "terms"]))
        else:
            out[name] = float("nan")
    out["meta_metric"] = meta_metric(out, specs)
    return out


def meta_metric(likelihoods: Mapping[str, float], specs: Mapping[str, FeatureSpec] = WOSAC_2025
                ) -> float:
    """Weighted sum of the features' likelihoods. A feature without a value (NaN: no agent
    had a valid step of it, e.g. no signal in the scene) counts as 1 for the Bernoulli
    features (nothing could go wrong) and leaves the histogram features' weights out,
    renormalising over those present; NaN when none is present."""
    total = weight = 0.0
    for name, spec in specs.items():
        value = likelihoods.get(name, float("nan"))
        if not np.isfinite(value):
            if spec.bins == 0:
                total += spec.weight
                weight += spec.weight
            continue
        total += spec.weight * value
        weight += spec.weight
    if weight == 0:
        return float("nan")
    full = sum(s.weight for s in specs.values())
    return float(total / weight * full)
