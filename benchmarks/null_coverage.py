"""How often the same-policy null's difference intervals hold the true difference, for
coverage and novelty, whole labels and segments, paired and unpaired.

    PYTHONPATH=$PWD python benchmarks/null_coverage.py [--replications 300]

The data: label distributions of known shape (Zipf over 40 whole labels; for segments,
each episode 2-4 segments drawn from 12 segment labels). The reference has N trajectories
(30 rollouts, as a suite's seeds, or 100), the policy 30 episodes. Cases: "same" (the
policy draws from the reference's distribution: true difference about 0), "different"
(another distribution), "paired" (rollouts on the same seeds: on each seed the policy
repeats the reference's label with probability 0.5, else draws from another
distribution), "windows" (the policy's 30 units are 3 windows of each of 10 episodes, as
`bench run --womd` cuts 30 s episodes against 9.1 s WOMD tracks: each window repeats its
episode's label with probability 0.8, else draws its own; run once resampled by whole
episodes, the cluster bootstrap `bench run` uses, and once as if independent, as before).
For the windows cases the novel rate's Wilson interval is checked too (its truth: the
probability a window's label is one the data set's reference never shows). The true
difference is the mean of the estimate over 2000 fresh data sets
(:func:`tap_bench.bench.scores.null.same_policy_null`'s estimand: the difference at half sizes).
Each replication runs the null with 1000 draws and records whether each interval method
holds the truth.

"scenes" cases (``--only scenes``): the reference is a corpus like WOMD's vehicles, N
trajectories in S scenes of equal size, each scene drawing its own label probabilities
from Dirichlet(kappa p) around the population's (scene random effects); the policy's 30
episodes are independent (each its own scene: marginally p, "same"; or the "different"
mixture). Each is run with the reference's scenes known (``Reference.scenes``: the null
splits and resamples whole scenes) and without them (trajectories split and resampled one
by one, as before); each against its own estimand (the mean of its estimate over fresh
data sets, ``--truth`` of them). Prints a Markdown table (docs/benchmark.md) and writes
benchmarks/out/null_coverage.json.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import report

from tap_bench.bench.scores import null
from tap_bench.bench.scores.coverage import Reference
from tap_bench.bench.scores.novelty import novelty
from tap_bench.bench.scores.windows import window_episode
from tap_bench.stats.bootstrap import BootstrapConfig

K_LABELS, K_SEGMENTS = 40, 12


def _zipf(k: int, s: float, reverse: bool = False) -> np.ndarray:
    p = 1 / np.arange(1, k + 1) ** s
    p = p[::-1] if reverse else p
    return p / p.sum()


def _labels(p: np.ndarray, n: int, rng: np.random.Generator, unit: str) -> np.ndarray:
    """n labels: whole labels ``L07 | X``, or 2-4 segment labels ``A03 > A07 | X``."""
    if unit == "episodes":
        return np.array([f"L{i:02d} | X" for i in rng.choice(len(p), n, p=p)], object)
    out = []
    for _ in range(n):
        k = rng.integers(2, 5)
        out.append(" > ".join(f"A{i:02d}" for i in rng.choice(len(p), k, p=p)) + " | X")
    return np.array(out, object)


def _reference(units: np.ndarray, unit: str, paired: bool,
               scenes: np.ndarray | None = None) -> Reference:
    kind = "segments" if unit == "segments" else "corpus"
    return Reference(np.zeros(0, object), np.zeros(0), kind, "maneuver", "synthetic",
                     n_trajectories=len(units), units=units,
                     seeds=np.arange(len(units)) if paired else None, scenes=scenes)


def _scene_of(case: dict) -> np.ndarray | None:
    """(N,) the scene of each reference trajectory of a "scenes" case (equal scenes)."""
    if not case.get("scenes"):
        return None
    return np.arange(case["N"]) // (case["N"] // case["scenes"])


def _sample(case: dict, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    if case.get("scenes"):  # scene random effects: each scene its own probabilities
        scene = _scene_of(case)
        probs = rng.dirichlet(case["kappa"] * case["p_ref"], case["scenes"])
        cum = probs.cumsum(axis=1)[scene]
        pick = np.minimum((rng.random(len(scene))[:, None] > cum).sum(axis=1),
                          len(case["p_ref"]) - 1)
        ref = np.array([f"L{i:02d} | X" for i in pick], object)
    else:
        ref = _labels(case["p_ref"], case["N"], rng, case["unit"])
    pol = _labels(case["p_pol"], case["n"], rng, case["unit"])
    if case.get("windows"):  # each episode's windows repeat its label with prob. `rho`
        w = case["windows"]
        episode = np.repeat(pol[::w], w)
        pol = np.where(rng.random(len(pol)) < case["rho"], episode, pol)
    if case["paired"]:  # the same seed: the reference's label with probability `repeat`
        same = rng.random(case["n"]) < case["repeat"]
        pol = np.where(same, ref[:case["n"]], pol)
    return ref, pol


def _estimate(ref, pol, case, rng, draws: int, splits: int = null.SPLITS):
    reference = _reference(ref, case["unit"], case["paired"],
                           _scene_of(case) if case.get("by_scene") else None)
    seeds = np.arange(len(pol)) if case["paired"] else None
    clusters = window_episode(_episodes(case)) if case.get("by_episode") else None
    return null.same_policy_null(pol, reference, seeds=seeds, rng=rng, splits=splits,
                                 clusters=clusters,
                                 config=BootstrapConfig(n_resamples=draws, seed=0))


def _episodes(case: dict) -> np.ndarray:
    """(n,) each window's scenario id, ``ep<k>#<window>`` (:func:`window_episode`: its
    episode)."""
    w = case.get("windows") or 1
    return np.array([f"ep{i // w}#{i % w}" for i in range(case["n"])], object)


def _novel_rate_holds(ref, pol, case) -> tuple[bool, float]:
    """Whether the novel rate's Wilson interval holds the probability a window is novel
    against this reference, and its width."""
    items = np.unique(ref)
    reference = Reference(items, np.full(len(items), 1 / len(items)), "corpus", "maneuver",
                          "synthetic", n_trajectories=len(ref), units=ref)
    names = np.array([f"L{i:02d} | X" for i in range(len(case["p_pol"]))], object)
    truth = float(case["p_pol"][~np.isin(names, items)].sum())
    episodes = pd.DataFrame({"sdl": pol, "scenario_id": _episodes(case),
                             "cut_from": window_episode(_episodes(case))})
    r = novelty(episodes, reference, config=BootstrapConfig(n_resamples=500, seed=0),
                windowed=bool(case.get("by_episode")))
    return bool(r.rate_low <= truth <= r.rate_high), r.rate_high - r.rate_low


def holds_and_widths(truth, hits, widths, replications: int) -> dict[str, float]:
    """The row figures of a study: the true (coverage, novelty) differences, the share of
    data sets whose interval held each, and each interval's mean width."""
    return {"true_coverage_diff": round(float(truth[0]), 3),
            "true_novel_diff": round(float(truth[1]), 3),
            "coverage_hits": round(float(hits[0] / replications), 3),
            "novel_hits": round(float(hits[1] / replications), 3),
            "coverage_width": round(float(widths[0] / replications), 3),
            "novel_width": round(float(widths[1] / replications), 3)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--replications", type=int, default=300)
    parser.add_argument("--truth", type=int, default=2000, help="data sets for the truth")
    parser.add_argument("--method", default=null.METHOD, choices=("recentred", "shrunk"))
    parser.add_argument("--only", choices=("all", "windows", "scenes"), default="all",
                        help="run every case, or only the windows or the scenes cases")
    parser.add_argument("--scene-methods", nargs="+", default=["by scene", "by trajectory"],
                        choices=("by scene", "by trajectory"),
                        help="the scenes cases' resampling (both)")
    args = parser.parse_args()
    null.METHOD = args.method
    cases = []
    for unit, k in (("episodes", K_LABELS), ("segments", K_SEGMENTS)):
        same, other = _zipf(k, 1.1), _zipf(k, 1.1, reverse=True)
        for N in (30, 100):
            cases += [
                {"unit": unit, "name": "same", "N": N, "n": 30, "paired": False,
                 "p_ref": same, "p_pol": same, "repeat": 0.0},
                {"unit": unit, "name": "different", "N": N, "n": 30, "paired": False,
                 "p_ref": same, "p_pol": 0.5 * same + 0.5 * other, "repeat": 0.0}]
        cases.append({"unit": unit, "name": "paired", "N": 30, "n": 30, "paired": True,
                      "p_ref": same, "p_pol": other, "repeat": 0.5})
    same, other = _zipf(K_LABELS, 1.1), _zipf(K_LABELS, 1.1, reverse=True)
    windows = [{"unit": "episodes", "name": f"windows, {how}", "N": N, "n": 30,
                "paired": False, "p_ref": same, "p_pol": 0.5 * same + 0.5 * other,
                "repeat": 0.0, "windows": 3, "rho": 0.8, "by_episode": how == "by episode"}
               for N in (30, 100) for how in ("by episode", "as independent")]
    scene_cases = [{"unit": "episodes", "name": f"{S} scenes, {what}, {how}", "N": N,
                    "n": 30, "paired": False, "p_ref": same, "p_pol": p_pol, "repeat": 0.0,
                    "scenes": S, "kappa": 2.0, "by_scene": how == "by scene"}
                   for N, S in ((300, 10), (600, 40))
                   for what, p_pol in (("same", same), ("different",
                                                        0.5 * same + 0.5 * other))
                   for how in args.scene_methods]
    cases = {"windows": windows, "scenes": scene_cases}.get(args.only, cases + windows)
    rng = np.random.default_rng(25)
    rows = []
    start, cpu = time.perf_counter(), time.process_time()
    for case in cases:
        truth = np.mean([[r.coverage_diff, r.novel_diff] for r in (
            _estimate(*_sample(case, rng), case, rng, draws=100, splits=20)
            for _ in range(args.truth))], axis=0)
        hits, widths = np.zeros(2), np.zeros(2)
        rate_hits, rate_width = 0, 0.0
        for _ in range(args.replications):
            data = _sample(case, rng)
            r = _estimate(*data, case, rng, draws=1000)
            if case.get("windows"):
                holds, width = _novel_rate_holds(*data, case)
                rate_hits, rate_width = rate_hits + holds, rate_width + width
            lows = np.array([r.coverage_diff_low, r.novel_diff_low])
            highs = np.array([r.coverage_diff_high, r.novel_diff_high])
            hits += (lows <= truth) & (truth <= highs)
            widths += highs - lows
        row = {"unit": case["unit"], "case": case["name"], "reference": case["N"],
               "policy": case["n"], "paired": case["paired"],
               **holds_and_widths(truth, hits, widths, args.replications)}
        if case.get("windows"):
            row["novel_rate_hits"] = round(rate_hits / args.replications, 3)
            row["novel_rate_width"] = round(rate_width / args.replications, 3)
        rows.append(row)
        print(row, flush=True)
    print("\n| unit | case | reference N | policy n | true coverage diff | interval holds it "
          "| width | true novelty diff | interval holds it | width |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['unit']} | {r['case']}{' (paired)' if r['paired'] else ''} | "
              f"{r['reference']} | {r['policy']} | {r['true_coverage_diff']:+.3f} | "
              f"{r['coverage_hits']:.2f} | {r['coverage_width']:.2f} | "
              f"{r['true_novel_diff']:+.3f} | {r['novel_hits']:.2f} | {r['novel_width']:.2f} |")
    for r in rows:
        if "novel_rate_hits" in r:
            print(f"{r['case']}, reference N {r['reference']}: the novel rate's Wilson "
                  "interval holds it "
                  f"{r['novel_rate_hits']:.2f}, width {r['novel_rate_width']:.2f}")
    report(f"null_coverage_{args.method}" + ("" if args.only == "all" else f"_{args.only}"), {
        "method": args.method, "replications": args.replications, "rows": rows,
        "wall_s": round(time.perf_counter() - start, 1),
        "cpu_s": round(time.process_time() - cpu, 1)}, seed=25)


if __name__ == "__main__":
    main()
