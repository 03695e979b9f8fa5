"""Coverage of the realism score's intervals (percentile bootstrap over scenes,
:mod:`tap_bench.realism.summary`): per-scene meta-metrics drawn from Beta distributions
shaped like the measured ones (mean 0.6-0.9, spread as over the real scenes), n scenes,
the 95 % interval of the mean checked against the true mean over many trials.

Usage: ``python benchmarks/realism_interval_coverage.py [--trials 1000]``
"""

from __future__ import annotations

import argparse

import numpy as np
from machine import report

from tap_bench.realism.summary import _interval
from tap_bench.stats.bootstrap import BootstrapConfig, named_rng


def coverage(n: int, mean: float, sd: float, trials: int, resamples: int) -> float:
    k = mean * (1 - mean) / sd ** 2 - 1  # Beta(a, b) with this mean and sd
    a, b = mean * k, (1 - mean) * k
    rng = named_rng(0, "realism coverage", n, mean, sd)
    config = BootstrapConfig(n_resamples=resamples)
    hits = 0
    for _ in range(trials):
        values = rng.beta(a, b, n)
        weights = rng.multinomial(n, np.full(n, 1 / n), size=resamples).astype(float)
        lo, hi = _interval(values, weights, config.level)
        hits += lo <= mean <= hi
    return hits / trials


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=1000)
    parser.add_argument("--resamples", type=int, default=1000)
    args = parser.parse_args()
    figures = {}
    for n in (8, 16, 50):
        for mean, sd in ((0.65, 0.12), (0.8, 0.08), (0.9, 0.05)):
            c = coverage(n, mean, sd, args.trials, args.resamples)
            figures[f"n{n}_mean{mean}_sd{sd}"] = c
            print(f"{n:3d} scenes, mean {mean:.2f}, sd {sd:.2f}: coverage {c:.3f}")
    report("realism_interval_coverage", figures, seed=0)


if __name__ == "__main__":
    main()
