"""How often each interval of tap_bench.bench holds the truth: interval type x seeds
(10, 30, 100) x true effect, on synthetic data whose true value is known.

    PYTHONPATH=$PWD python benchmarks/interval_coverage.py [--replications 1000]

Prints a Markdown table (the one in docs/benchmark.md) and writes
benchmarks/out/interval_coverage.json with the machine and the seeds. Every row is the
share of replications whose 95 % interval holds the true value; its Monte Carlo standard
error is about 0.007 at 1000 replications (0.013 at 300, used for the bootstrap-based
intervals, which are slower).

The data: proportions are Bernoulli; paired outcomes share a seed effect (a common uniform
draw, 70 % of the seeds correlated); measure differences are skewed (exponential plus
normal noise, the shape of the demo's per-seed jerk and TTC differences); label
distributions are Zipf over 30 labels (exponent 0.8, 1.2, 2: from near-uniform to one
dominant label, the range seen between the random policy and IDM) and, for the diversity
rows, a log-normal over 60 labels.

Proportions of tracks in scenes (agreement of WOMD tracks with Waymo's classifier): the
"seeds" are scenes of 1 + Poisson(20) tracks, each scene agreeing with its own
probability (Beta, mean p, intra-scene correlation 0.2); Wilson's interval over the tracks
as if independent against the clustered one (``clustered_wilson_interval``).

Each interval is held against the quantity it is for: coverage against the expected
coverage of n episodes, the Hill numbers at m against Chao et al. (2014)'s qD(m) of the
true distribution (``population_hill``: exact, no simulation; for q = 1, 2 not the mean of
the sample's own Hill number), completeness against the sample's own coverage.
Coverage of windows (``--only windows``): each of n episodes is cut into 3 windows, each
repeating its episode's label with probability 0.8, else drawing its own (as
``gap_coverage.py``'s windows); the truth is the expected coverage of n such episodes
(exact: a label is missed when none of an episode's windows shows it).
``--only TEXT`` runs only the rows whose interval name contains TEXT (``diversity``,
``coverage``). The whole table takes about a minute on 2 cores.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import report

from tap_bench.bench.scores.coverage import Reference, coverage
from tap_bench.bench.scores.diversity import diversity, population_hill
from tap_bench.stats.bootstrap import BootstrapConfig
from tap_bench.stats.intervals import (
    clustered_wilson_interval,
    mean_interval,
    tango_band,
    tango_interval,
    welch_interval,
    wilson_interval,
)

LEVEL = 0.95
SEEDS = (10, 30, 100)


def wilson_rate(rng, n, p, reps):
    x = rng.binomial(n, p, reps)
    lo, hi = wilson_interval(x, np.full(reps, n), LEVEL)
    return np.mean((lo <= p) & (p <= hi))


def _scene_shares(rng, n, p, reps, icc=0.2, tracks=20):
    """reps data sets of n scenes of 1 + Poisson(tracks) tracks, each scene agreeing with
    its own probability, Beta with mean p and intra-scene correlation ``icc``: (x, m) lists
    of per-scene successes and tracks."""
    ab = 1 / icc - 1
    out = []
    for _ in range(reps):
        m = 1 + rng.poisson(tracks, n)
        out.append((rng.binomial(m, rng.beta(p * ab, (1 - p) * ab, n)), m))
    return out


def wilson_tracks_rate(rng, n, p, reps):
    """Wilson's interval over the tracks, as if independent (tracks of n scenes)."""
    hits = [(lo <= p <= hi) for lo, hi in (wilson_interval(int(x.sum()), int(m.sum()), LEVEL)
                                           for x, m in _scene_shares(rng, n, p, reps))]
    return np.mean(hits)


def clustered_wilson_rate(rng, n, p, reps):
    """Wilson's interval at n / deff over the scenes (clustered_wilson_interval)."""
    hits = [(lo <= p <= hi) for lo, hi, _ in (clustered_wilson_interval(x, m, LEVEL)
                                              for x, m in _scene_shares(rng, n, p, reps))]
    return np.mean(hits)


def _paired_binary(rng, n, pa, pb, reps):
    u = rng.random((reps, n))
    a = u < pa
    b = np.where(rng.random((reps, n)) < 0.7, u, rng.random((reps, n))) < pb
    return a, b


def tango_rate(rng, n, delta, reps):
    pb = 0.3
    a, b = _paired_binary(rng, n, pb + delta, pb, reps)
    lo, hi = tango_interval((a & ~b).sum(1), (b & ~a).sum(1), np.full(reps, n), LEVEL)
    return np.mean((lo <= delta) & (delta <= hi))


def improvement_rate(rng, n, p_win, reps):
    # per seed: A better with p_win - 0.1, worse with 0.9 - p_win, tie 0.2: P = p_win
    probs = [p_win - 0.1, 0.2, 0.9 - p_win]
    outcome = rng.choice(3, size=(reps, n), p=probs)
    wins, losses = (outcome == 0).sum(1), (outcome == 2).sum(1)
    lo, hi = tango_interval(wins, losses, np.full(reps, n), LEVEL)
    truth = 2 * (p_win - 0.1 + 0.1) - 1  # (wins - losses) / n has mean 2 P - 1
    return np.mean((lo <= truth) & (truth <= hi))


def band_rate(rng, n, effect, reps):
    K = 8
    pb = np.full(K, 1.0 / K)
    pa = pb + effect * np.linspace(-1, 1, K) / K * 2
    pa = np.clip(pa, 0.01, None)
    pa /= pa.sum()
    truth = pa - pb
    hits = 0
    for _ in range(reps):
        la, lb = rng.choice(K, n, p=pa), rng.choice(K, n, p=pb)
        ina = la[:, None] == np.arange(K)
        inb = lb[:, None] == np.arange(K)
        lo, hi = tango_band(ina & ~inb, inb & ~ina, LEVEL, rng, 400)
        hits += np.all((lo <= truth) & (truth <= hi))
    return hits / reps


def paired_t_rate(rng, n, effect, reps):
    d = effect + rng.exponential(1.0, (reps, n)) - 1.0 + rng.normal(0, 0.5, (reps, n))
    hits = [lo <= effect <= hi for lo, hi in (mean_interval(row, LEVEL) for row in d)]
    return np.mean(hits)


def welch_rate(rng, n, effect, reps):
    half = max(n // 2, 2)
    a = effect + rng.exponential(1.0, (reps, half))
    b = rng.exponential(1.5, (reps, half)) - 0.5
    truth = effect + 1.0 - 1.0
    hits = [lo <= truth <= hi for lo, hi in (welch_interval(x, y, LEVEL) for x, y in
                                             zip(a, b, strict=True))]
    return np.mean(hits)


def _zipf(exponent, K=30):
    p = 1 / np.arange(1, K + 1) ** exponent
    return p / p.sum()


def coverage_rate(rng, n, exponent, reps):
    K = 30
    p = _zipf(exponent, K)
    items = np.array([f"L{i:02d}" for i in range(K)], dtype=object)
    ref = Reference(items, np.full(K, 1 / K), "corpus", "maneuver", "synthetic")
    truth = np.mean(1 - (1 - p) ** n)
    hits = 0
    for r in range(reps):
        labels = items[rng.choice(K, n, p=p)]
        res = coverage(labels, ref, config=BootstrapConfig(n_resamples=500, seed=r),
                       rng=rng)
        hits += res.coverage_low <= truth <= res.coverage_high
    return hits / reps


def _window_labels(rng, items, p, n, windows=3, repeat=0.8):
    """n episodes' labels and ``windows`` windows of each: a window repeats its episode's
    label with probability ``repeat``, else draws its own (``gap_coverage.py``'s windows)."""
    own = items[rng.choice(len(items), n, p=p)]
    labels = np.where(rng.random((n, windows)) < repeat, own[:, None],
                      items[rng.choice(len(items), (n, windows), p=p)])
    return labels.ravel(), np.repeat(np.arange(n).astype(str), windows).astype(object)


def _window_coverage_rate(rng, n, exponent, reps, by_episode):
    K, windows, repeat = 30, 3, 0.8
    p = _zipf(exponent, K)
    items = np.array([f"L{i:02d}" for i in range(K)], dtype=object)
    ref = Reference(items, np.full(K, 1 / K), "corpus", "maneuver", "synthetic")
    # an episode misses label i when no window shows it (its own label i or not)
    missed = (1 - p) * (1 - (1 - repeat) * p) ** windows \
        + p * ((1 - repeat) * (1 - p)) ** windows
    truth = np.mean(1 - missed ** n)
    hits = 0
    for r in range(reps):
        labels, episodes = _window_labels(rng, items, p, n, windows, repeat)
        res = coverage(labels, ref, config=BootstrapConfig(n_resamples=500, seed=r),
                       rng=rng, clusters=episodes if by_episode else None)
        hits += res.coverage_low <= truth <= res.coverage_high
    return hits / reps


def window_coverage_rate(rng, n, exponent, reps):
    return _window_coverage_rate(rng, n, exponent, reps, True)


def window_coverage_iid_rate(rng, n, exponent, reps):
    return _window_coverage_rate(rng, n, exponent, reps, False)


def _lognormal(K=60):
    """A log-normal assemblage (sd 1.5 on the log scale) of K labels, fixed by seed 99."""
    p = np.exp(np.random.default_rng(99).normal(0.0, 1.5, K))
    return p / p.sum()


ASSEMBLAGES = {  # name: label probabilities
    "Zipf 0.8, 30 labels": _zipf(0.8),
    "Zipf 1.2, 30 labels": _zipf(1.2),
    "Zipf 2, 30 labels": _zipf(2.0),
    "log-normal, 60 labels": _lognormal(),
}


def hill_rates(rng, n, p, reps, size=None):
    """(q0, q1, q2, completeness) interval hit rates at m = size (default n).

    The estimand of the Hill numbers is what the point estimate estimates: the Hill number
    at m of the expected label-frequency profile (Chao et al. 2014's qD(m),
    :func:`population_hill` of the true distribution; for q = 1, 2 this is not the mean
    of the sample's own Hill number, which Jensen's inequality puts above it). An "at
    least" result (extrapolation beyond 2n or from completeness < 0.5) holds when its
    lower bound does. Completeness's estimand is the sample's own coverage, the sum of p
    over the labels seen."""
    K = len(p)
    m = size or n
    truth = population_hill(p, m)
    items = np.array([f"L{i:02d}" for i in range(K)], dtype=object)
    hits = np.zeros(4)
    for _ in range(reps):
        idx = rng.choice(K, n, p=p)
        d = diversity(items[idx], size=m, config=BootstrapConfig(n_resamples=300), rng=rng)
        high = np.where(np.isnan(d.hill_high), np.inf, d.hill_high)
        hits[:3] += (d.hill_low <= truth) & (truth <= high)
        seen = p[np.unique(idx)].sum()
        hits[3] += d.completeness_low <= seen <= d.completeness_high
    return hits / reps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--replications", type=int, default=1000)
    parser.add_argument("--bootstrap-replications", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--only", default="", help="run only the rows whose interval "
                        "name contains this text, e.g. 'diversity' or 'coverage'")
    args = parser.parse_args()
    reps, breps = args.replications, args.bootstrap_replications
    rng = np.random.default_rng(args.seed)
    start = time.perf_counter()
    rows = []

    def wanted(kind):
        return args.only.lower() in kind.lower()

    def add(kind, effect_name, effects, fn, r):
        if not wanted(kind):
            return
        for effect in effects:
            rates = [float(fn(rng, n, effect, r)) for n in SEEDS]
            rows.append({"interval": kind, "true effect": f"{effect_name} {effect:g}",
                         **{f"{n} seeds": rate for n, rate in zip(SEEDS, rates, strict=True)},
                         "replications": r})
            print(rows[-1], flush=True)

    add("Wilson: crash / novelty rate, agreement", "p", (0.03, 0.25, 0.5), wilson_rate, reps)
    add("Wilson over tracks, as if independent: agreement of tracks in scenes (before)",
        "p (ICC 0.2)", (0.1, 0.5, 0.8), wilson_tracks_rate, reps)
    add("clustered Wilson (n / deff over scenes): agreement of tracks in scenes", "p (ICC 0.2)",
        (0.1, 0.5, 0.8), clustered_wilson_rate, reps)
    add("Tango: paired label-frequency / crash-rate difference", "delta", (0.0, 0.1, 0.3),
        tango_rate, reps)
    add("Tango: probability of improvement (20 % ties)", "P", (0.5, 0.7, 0.9),
        improvement_rate, reps)
    add("sup-score band, 8 labels jointly", "max |delta|", (0.0, 0.1, 0.2), band_rate, breps)
    add("paired t: measure difference (skewed)", "mean", (0.0, 0.5, 2.0), paired_t_rate, reps)
    add("Welch t: matched-group difference (n/2 per policy)", "mean", (0.0, 1.0),
        welch_rate, reps)
    add("coverage of 30 reference labels", "Zipf exponent", (0.8, 1.2, 2.0),
        coverage_rate, breps)
    add("coverage of 30 reference labels, 3 windows an episode (seeds: episodes), "
        "resampled by episode", "Zipf exponent", (0.8, 1.2, 2.0), window_coverage_rate,
        breps)
    add("coverage of 30 reference labels, 3 windows an episode (seeds: episodes), windows "
        "as independent (before)", "Zipf exponent", (0.8, 1.2, 2.0),
        window_coverage_iid_rate, breps)
    for name, p in ASSEMBLAGES.items() if wanted("diversity") else ():
        rates = [hill_rates(rng, n, p, breps) for n in SEEDS]
        for j, what in enumerate(("Hill q0", "Hill q1", "Hill q2", "sample completeness")):
            rows.append({"interval": f"diversity: {what}", "true effect": name,
                         **{f"{n} seeds": float(r[j]) for n, r in zip(SEEDS, rates,
                                                                      strict=True)},
                         "replications": breps})
            print(rows[-1], flush=True)
    p = ASSEMBLAGES["Zipf 1.2, 30 labels"]
    for label, factor in ((("rarefied to n/2", 0.5), ("extrapolated to 2n", 2.0))
                          if wanted("diversity") else ()):
        rates = [hill_rates(rng, n, p, breps, size=round(n * factor)) for n in SEEDS]
        for j, what in enumerate(("Hill q0", "Hill q1", "Hill q2")):
            rows.append({"interval": f"diversity: {what} {label}",
                         "true effect": "Zipf 1.2, 30 labels",
                         **{f"{n} seeds": float(r[j]) for n, r in zip(SEEDS, rates,
                                                                      strict=True)},
                         "replications": breps})
            print(rows[-1], flush=True)
    print()
    print("| interval | true effect | 10 seeds | 30 seeds | 100 seeds |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['interval']} | {r['true effect']} | {r['10 seeds']:.3f} | "
              f"{r['30 seeds']:.3f} | {r['100 seeds']:.3f} |")
    report("interval_coverage", {"level": LEVEL, "rows": rows,
                                 "seconds": time.perf_counter() - start}, seed=args.seed)


if __name__ == "__main__":
    main()
