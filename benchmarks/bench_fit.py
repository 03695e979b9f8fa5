"""Fit Theta_w, Theta_a, Theta_v from ~233,000 one-second samples: three starts, 100 epochs,
plus the grid, including the sort. Also each method alone and all four together.

Usage: ``python benchmarks/bench_fit.py [--repeats 5]``. The samples are the one-second
windows of 25,889 synthetic 91-step trajectories (9 windows each: 233,001 samples).
"""

from __future__ import annotations

import argparse
import time

from machine import report

import tap_bench as tb
from tap_bench.fitting import fit_report


def best_of(repeats: int, fn) -> tuple[float, float, object]:
    """Best wall time, best CPU time (of this process) and the last result."""
    times, cpu, out = [], [], None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return min(times), min(cpu), out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--n", type=int, default=25889)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    samples = tb.one_second_samples(tb.random_trajectories(args.n, seed=args.seed))
    figures = {"samples": {k: len(v) for k, v in samples.items()}}
    for name, methods in [("descent+grid", ("descent", "grid")),
                          ("descent", ("descent",)), ("descent-scaled", ("descent-scaled",)),
                          ("cem", ("cem",)), ("grid", ("grid",)),
                          ("all four", ("descent", "descent-scaled", "cem", "grid"))]:
        seconds, cpu, rep = best_of(args.repeats,
                                    lambda m=methods: fit_report(samples, methods=m))
        figures[f"{name}_s"] = round(seconds, 4)
        figures[f"{name}_cpu_s"] = round(cpu, 4)
        if name == "all four":
            table = rep.table()
            figures["all_four_table"] = table.round(6).to_dict(orient="records")
            figures["chosen"] = {d: rep.thresholds.of(d) for d in ("w", "a", "v")}
    report("fit_speed", figures, repeats=args.repeats, seed=args.seed,
           note="times include sorting the samples; best wall and best CPU time of the "
           "repeats")


if __name__ == "__main__":
    main()
