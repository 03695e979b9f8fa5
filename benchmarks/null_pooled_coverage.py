"""How often the pooled same-policy null's difference intervals (the "all" rows of
coverage and novelty: :func:`tap_bench.bench.scores.null.pooled_null`, estimate +- z sd of the
envs' draws combined as independent) hold the true pooled difference.

    PYTHONPATH=$PWD python benchmarks/null_pooled_coverage.py [--replications 300]

The data: three envs, each with its own label distribution (Zipf 0.8, 1.1 and 1.5 over 40
whole labels, or 2-4 segments per episode from 12 segment labels), a reference of 30
rollouts and a policy of 30 episodes per env, as ``benchmarks/null_coverage.py`` draws
them: "different" (half the probability moved to the reversed Zipf) and "paired" (on each
seed the policy repeats the reference's label with probability 0.5, else draws from the
reversed Zipf). The pooling weights are scoring's: each env's reference items (K: its
distinct labels, or segment labels) for coverage, its episodes for novelty. The true
difference is the mean pooled estimate over ``--truth`` fresh data sets; each replication
runs every env's null with 1000 draws, pools them and records whether each interval holds
the truth. Prints a Markdown table and writes benchmarks/out/null_pooled_coverage.json.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import null_coverage as single
from machine import report

from tap_bench.bench.scores import null
from tap_bench.bench.scores.coverage import unit_items

SHAPES = (0.8, 1.1, 1.5)
"""Zipf exponents of the three envs' reference distributions."""


def _envs(unit: str, paired: bool) -> list[dict]:
    k = single.K_LABELS if unit == "episodes" else single.K_SEGMENTS
    envs = []
    for s in SHAPES:
        same, other = single._zipf(k, s), single._zipf(k, s, reverse=True)
        envs.append({"unit": unit, "N": 30, "n": 30, "paired": paired, "p_ref": same,
                     "p_pol": other if paired else 0.5 * same + 0.5 * other,
                     "repeat": 0.5})
    return envs


def _pooled(envs: list[dict], rng: np.random.Generator, draws: int,
            splits: int = null.SPLITS) -> null.NullResult:
    results, k_weights, n_weights = [], [], []
    for case in envs:
        ref, pol = single._sample(case, rng)
        results.append(single._estimate(ref, pol, case, rng, draws=draws, splits=splits))
        reference = single._reference(ref, case["unit"], case["paired"])
        items = ({(u,) for u in ref} if case["unit"] == "episodes"
                 else {x for row in unit_items(ref, reference.axes) for x in row})
        k_weights.append(len(items))  # the reference's items (coverage's K)
        n_weights.append(len(pol))
    return null.pooled_null(results, k_weights, n_weights, 0.95)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--replications", type=int, default=300)
    parser.add_argument("--truth", type=int, default=600, help="data sets for the truth")
    args = parser.parse_args()
    rng = np.random.default_rng(26)
    rows = []
    start, cpu = time.perf_counter(), time.process_time()
    for unit in ("episodes", "segments"):
        for paired in (False, True):
            envs = _envs(unit, paired)
            truth = np.mean([[r.coverage_diff, r.novel_diff] for r in (
                _pooled(envs, rng, draws=100, splits=20) for _ in range(args.truth))],
                axis=0)
            hits, widths = np.zeros(2), np.zeros(2)
            for _ in range(args.replications):
                r = _pooled(envs, rng, draws=1000)
                lows = np.array([r.coverage_diff_low, r.novel_diff_low])
                highs = np.array([r.coverage_diff_high, r.novel_diff_high])
                hits += (lows <= truth) & (truth <= highs)
                widths += highs - lows
            row = {"unit": unit, "case": "paired" if paired else "different", "envs": 3,
                   "reference": 30, "policy": 30,
                   **single.holds_and_widths(truth, hits, widths, args.replications)}
            rows.append(row)
            print(row, flush=True)
    print("\n| unit | case | true coverage diff | interval holds it | width "
          "| true novelty diff | interval holds it | width |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['unit']} | {r['case']} | {r['true_coverage_diff']:+.3f} | "
              f"{r['coverage_hits']:.2f} | {r['coverage_width']:.2f} | "
              f"{r['true_novel_diff']:+.3f} | {r['novel_hits']:.2f} | {r['novel_width']:.2f} |")
    report("null_pooled_coverage", {
        "replications": args.replications, "truth": args.truth, "rows": rows,
        "wall_s": round(time.perf_counter() - start, 1),
        "cpu_s": round(time.process_time() - cpu, 1)}, seed=26)


if __name__ == "__main__":
    main()
