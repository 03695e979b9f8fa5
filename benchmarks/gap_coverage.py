"""How often the sim-to-real gap's intervals hold the true gap: samples of the same
behaviour (true gap 0) and of different behaviour (true gap about 0.1 and 0.25).

    PYTHONPATH=$PWD python benchmarks/gap_coverage.py [--replications 300]

The data: each trajectory shows one lateral, one longitudinal and one interaction label
(real SDL tokens), drawn from per-axis distributions; the reference has 300 trajectories
(WOMD-like), the policy 30 or 100 episodes. "same": the policy draws from the reference's
distributions; "different": a share of each axis's probability moved to other labels.
The true gap is the total variation distance of the two populations' label shares
(exact). Each replication runs :func:`tap_bench.bench.gap.behaviour_gap` (1000
resamples) and records whether the plug-in's percentile interval (``gap_low``,
``gap_high``) and the debiased gap's basic interval (``debiased_low``,
``debiased_high``) hold the true gap, and each estimate's mean error. Prints a Markdown
table (docs/interactions.md) and writes benchmarks/out/gap_coverage.json.

"windows" cases (``--only windows`` runs just these): the policy's 30 units are 3 windows
of each of 10 episodes, as ``gap --window auto`` cuts 30 s episodes against 9.1 s WOMD
tracks; each window repeats its episode's labels with probability 0.8, else draws its
own. Each is run resampling the windows by whole episodes (the cluster bootstrap ``gap``
uses, ``behaviour_gap(..., clusters=)``) and as if independent (as before).
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

from tap_bench.bench.bootstrap import BootstrapConfig
from tap_bench.bench.gap import behaviour_gap

AXES = {"lateral": (["Straight", "Left Merge", "Right Merge", "Left Turn", "Right Turn"],
                    [0.6, 0.15, 0.15, 0.05, 0.05]),
        "longitudinal": (["Maintain Speed", "Accelerate", "Decelerate", "Stopped"],
                         [0.5, 0.2, 0.25, 0.05]),
        "interaction": (["Free Driving", "Following", "Cut-in", "Being Overtaken"],
                        [0.4, 0.45, 0.05, 0.1])}


def _shifted(shift: float) -> dict[str, np.ndarray]:
    """Each axis's distribution with ``shift`` of its first label's probability moved to
    the others (equally)."""
    out = {}
    for axis, (_names, p) in AXES.items():
        p = np.array(p, float)
        moved = min(shift, p[0])
        p = p.copy()
        p[0] -= moved
        p[1:] += moved / (len(p) - 1)
        out[axis] = p
    return out


def _true_gap(pa: dict[str, np.ndarray], pb: dict[str, np.ndarray]) -> float:
    # every trajectory shows one label per axis: the shares are the axis probabilities / 3
    return float(sum(0.5 * np.abs(pa[a] - pb[a]).sum() / len(AXES) for a in AXES))


def _sample(p: dict[str, np.ndarray], n: int, rng: np.random.Generator) -> pd.DataFrame:
    return pd.DataFrame({axis: np.array(AXES[axis][0])[rng.choice(len(p[axis]), n,
                                                                  p=p[axis])]
                         for axis in AXES}).assign(mean_speed=np.nan)


def _windowed(p: dict[str, np.ndarray], n: int, rng: np.random.Generator, windows: int = 3,
              rho: float = 0.8) -> pd.DataFrame:
    """n windows, ``windows`` per episode, each repeating its episode's labels with
    probability ``rho``; ``episode`` names the episode."""
    own = _sample(p, n, rng)
    first = np.repeat(np.arange(0, n, windows), windows)[:n]
    repeat = rng.random(n) < rho
    out = own.copy()
    out.loc[repeat, list(AXES)] = own.iloc[first[repeat]][list(AXES)].to_numpy()
    return out.assign(episode=np.arange(n) // windows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--replications", type=int, default=300)
    parser.add_argument("--only", choices=("all", "windows"), default="all")
    args = parser.parse_args()
    reference = {a: np.array(p, float) for a, (_, p) in AXES.items()}
    cases = {"same behaviour": reference, "different, small": _shifted(0.12),
             "different, large": _shifted(0.4)}
    rng = np.random.default_rng(14)
    config = BootstrapConfig(n_resamples=1000, seed=0)
    rows = []
    start, cpu = time.perf_counter(), time.process_time()
    runs = [(case, p, n, None) for case, p in cases.items() for n in (30, 100)]
    runs += [(f"{case}, 3 windows an episode, {how}", cases[case], 30, how)
             for case in ("same behaviour", "different, small")
             for how in ("by episode", "as independent")]
    if args.only == "windows":
        runs = [r for r in runs if r[3] is not None]
    for case, p_policy, n_policy, how in runs:
        truth = _true_gap(p_policy, reference)
        hold_pct = hold_basic = 0
        err_plug, err_deb, floor = [], [], []
        for rep in range(args.replications):
            ref = _sample(reference, 300, rng)
            pol = (_sample(p_policy, n_policy, rng) if how is None
                   else _windowed(p_policy, n_policy, rng))
            res = behaviour_gap(pol, ref, config=BootstrapConfig(
                n_resamples=config.n_resamples, seed=rep),
                clusters="episode" if how == "by episode" else None)
            hold_pct += res.gap_low <= truth <= res.gap_high
            hold_basic += res.debiased_low - 1e-12 <= truth <= res.debiased_high + 1e-12
            err_plug.append(res.gap - truth)
            err_deb.append(res.gap_debiased - truth)
            floor.append(res.floor)
        n = args.replications
        rows.append({"case": case, "true_gap": truth, "n_policy": n_policy,
                     "n_reference": 300, "replications": n,
                     "percentile_coverage": hold_pct / n, "basic_coverage": hold_basic / n,
                     "plugin_bias": float(np.mean(err_plug)),
                     "debiased_bias": float(np.mean(err_deb)),
                     "floor": float(np.mean(floor))})
        print(rows[-1], flush=True)
    print()
    print("| case | true gap | policy episodes | plug-in gap: bias, percentile coverage | "
          "debiased gap: bias, basic coverage | floor |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['case']} | {r['true_gap']:.3f} | {r['n_policy']} | "
              f"{r['plugin_bias']:+.3f}, {r['percentile_coverage']:.2f} | "
              f"{r['debiased_bias']:+.3f}, {r['basic_coverage']:.2f} | {r['floor']:.3f} |")
    name = "gap_coverage" + ("_windows" if args.only == "windows" else "")
    report(name, {"rows": rows, "seconds": time.perf_counter() - start,
                  "cpu_seconds": time.process_time() - cpu,
                  "replications": args.replications}, seed=14)


if __name__ == "__main__":
    main()
