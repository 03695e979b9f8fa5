"""Coverage of the intervals of agents over training seeds x scenes
(:mod:`tap_bench.stats.aggregate`): the IQM's stratified bootstrap interval, the probability of
improvement's, and the performance profile's pointwise band at three thresholds.

Simulated agents: ``M`` scenes, each with its own difficulty mu_m ~ U(0.3, 0.9); a training
run n of an agent scores ``clip(mu_m + delta + s_n + e_nm, 0, 1)`` (delta: the agent's
edge; e_nm ~ N(0, 0.15) independent per run and scene). ``s_n`` is a seed effect shared by
every scene of one run (a good seed is good everywhere): ``--seed-sd 0`` (the bootstrap's
model: runs independent within each scene) and ``0.1`` (runs correlated across scenes, which
a bootstrap stratified by scene does not see). The true values are those of infinitely many
training seeds on the same scenes (the intervals hold the scenes fixed), computed from
20,000 simulated seeds. Each setting is repeated ``--trials`` times.

Both resampling units of the bootstrap are measured (``unit="task"``, rliable's stratified
bootstrap, and ``unit="run"``, whole seeds).

Usage: ``python benchmarks/agents_interval_coverage.py [--trials 200] [--resamples 500]``
"""

from __future__ import annotations

import argparse
import itertools
import time

import numpy as np
from machine import report

from tap_bench.stats.aggregate import (
    iqm,
    performance_profile,
    probability_of_improvement,
    stratified_bootstrap,
)
from tap_bench.stats.bootstrap import named_rng

NOISE_SD = 0.15
TAUS = (0.4, 0.6, 0.8)
BIG = 20_000  # simulated seeds of the true values


def scores(rng: np.random.Generator, mu: np.ndarray, runs: int, edge: float,
           seed_sd: float) -> np.ndarray:
    """(runs, scenes) scores of an agent with this edge."""
    seed_effect = rng.normal(0.0, seed_sd, size=(runs, 1)) if seed_sd > 0 else 0.0
    noise = rng.normal(0.0, NOISE_SD, size=(runs, len(mu)))
    return np.clip(mu[None, :] + edge + seed_effect + noise, 0.0, 1.0)


def true_improvement(x: np.ndarray, y: np.ndarray) -> float:
    """P(X > Y) of two large samples per scene (ties a half), averaged over scenes."""
    per = []
    for m in range(x.shape[1]):
        ys = np.sort(y[:, m])
        below = np.searchsorted(ys, x[:, m], side="left")
        upto = np.searchsorted(ys, x[:, m], side="right")
        per.append(np.mean(below + 0.5 * (upto - below)) / len(ys))
    return float(np.mean(per))


def setting(runs: int, scenes: int, seed_sd: float, trials: int, resamples: int,
            unit: str = "task") -> dict[str, float]:
    rng = named_rng(0, "agents coverage", runs, scenes, seed_sd)
    mu = rng.uniform(0.3, 0.9, scenes)  # the scenes stay fixed: the intervals condition on them
    big_x = scores(rng, mu, BIG, 0.05, seed_sd)
    big_y = scores(rng, mu, BIG, 0.0, seed_sd)
    true_iqm = iqm(big_x)
    true_poi = true_improvement(big_x[:4000], big_y[:4000])
    true_profile = np.array([(big_x > t).mean() for t in TAUS])
    hits = {"iqm": 0, "poi": 0, **{f"profile_{t}": 0 for t in TAUS}}
    widths = {"iqm": [], "poi": []}
    for _ in range(trials):
        x = scores(rng, mu, runs, 0.05, seed_sd)
        y = scores(rng, mu, runs, 0.0, seed_sd)
        out = stratified_bootstrap(x, iqm, rng=rng, n_resamples=resamples, unit=unit)
        hits["iqm"] += out.low <= true_iqm <= out.high
        widths["iqm"].append(out.high - out.low)
        poi = probability_of_improvement(x, y, rng=rng, n_resamples=resamples, unit=unit)
        hits["poi"] += poi.low <= true_poi <= poi.high
        widths["poi"].append(poi.high - poi.low)
        _, low, high = performance_profile(x, np.array(TAUS), rng=rng,
                                           n_resamples=resamples, unit=unit)
        for k, t in enumerate(TAUS):
            hits[f"profile_{t}"] += low[k] <= true_profile[k] <= high[k]
    out = {f"coverage_{k}": v / trials for k, v in hits.items()}
    out.update({f"width_{k}": float(np.mean(v)) for k, v in widths.items()})
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--resamples", type=int, default=500)
    args = parser.parse_args()
    figures: dict[str, float] = {"trials": args.trials, "resamples": args.resamples}
    start = time.process_time()
    for unit, seed_sd, runs, scenes in itertools.product(("task", "run"), (0.0, 0.1),
                                                         (3, 5, 10), (4, 16)):
        got = setting(runs, scenes, seed_sd, args.trials, args.resamples, unit)
        key = f"{unit}_sd{seed_sd}_runs{runs}_scenes{scenes}"
        figures.update({f"{key}_{k}": round(v, 4) for k, v in got.items()})
        print(f"resampling by {unit}, seed sd {seed_sd:.1f}, {runs:2d} runs x {scenes:2d} "
              f"scenes: IQM {got['coverage_iqm']:.3f} (width {got['width_iqm']:.3f}), "
              f"P(X>Y) {got['coverage_poi']:.3f} (width {got['width_poi']:.3f}), profile "
              + ", ".join(f"tau {t}: {got[f'coverage_profile_{t}']:.3f}" for t in TAUS),
              flush=True)
    figures["cpu_seconds"] = round(time.process_time() - start, 1)
    report("agents_interval_coverage", figures, seed=0)


if __name__ == "__main__":
    main()
