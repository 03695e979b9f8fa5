"""How often the sim-to-real gap's intervals hold the true gap: samples of the same
behaviour (true gap 0) and of different behaviour (true gap about 0.1 and 0.25).

    PYTHONPATH=$PWD python benchmarks/gap_coverage.py [--replications 300]

The data: each trajectory shows one lateral, one longitudinal and one interaction label
(real SDL tokens), drawn from per-axis distributions; the reference has 300 trajectories
(WOMD-like), the policy 30 or 100 episodes. "same": the policy draws from the reference's
distributions; "different": a share of each axis's probability moved to other labels.
The true gap is the total variation distance of the two populations' label shares
(exact). Each replication runs :func:`tap_bench.bench.scores.gap.behaviour_gap` (1000
resamples) and records whether the plug-in's percentile interval (``gap_low``,
``gap_high``) and the debiased gap's basic interval (``debiased_low``,
``debiased_high``) hold the true gap, and each estimate's mean error. Prints a Markdown
table (docs/interactions.md) and writes benchmarks/out/gap_coverage.json.

"windows" cases (``--only windows`` runs just these): the policy's 30 units are 3 windows
of each of 10 episodes, as ``gap --window auto`` cuts 30 s episodes against 9.1 s WOMD
tracks; each window repeats its episode's labels with probability 0.8, else draws its
own. Each is run resampling the windows by whole episodes (the cluster bootstrap ``gap``
uses, ``behaviour_gap(..., clusters=)``) and as if independent (as before).

"scenes" cases (``--only scenes``): the null of issue 38, vehicles of one scene share its
place, traffic and signals.

- **real**: the real WOMD scenes (``../shared/data/womd/*.tfrecord``, the ``.pkl``,
  ``../shared/data/womd-dev/dev.tfrecord``: 16 scenes) labelled with TAP at the maneuver
  level with every vehicle's interactions; each replication splits the scenes at random
  into two halves and compares one half's vehicles with the other's (both real driving:
  the true gap is 0). No speed range (both sides whole). 16 scenes give 12,870 splits of
  one fixed set of scenes, not independent data sets: this checks the method on real
  scenes' dependence, the synthetic rows are the evidence.
- **synthetic, scene effects**: each scene draws its own label probabilities per axis from
  a Dirichlet around the population's (concentration ``--kappa``, the intra-scene
  correlation about 1 / (kappa + 1)) and 1 + Poisson(``--vehicles``) vehicles each draw
  their labels from it; the two sides are independent sets of scenes from one population
  (null, true gap 0), or the policy's population turns left twice as often (``Left Turn``
  0.05 -> 0.10 of the lateral axis, the rest scaled down): its coverage of the true gap
  and its **power** (the share of replications whose interval excludes 0), and the same
  for the per-label interval of the ``Left Turn`` share difference (true difference
  0.05 / 3: each trajectory shows three labels, one per axis).

Run against any checkout (before / after a change) with ``PYTHONPATH`` naming it;
``--tag`` names the output file (``benchmarks/out/gap_coverage_scenes_<tag>.json``).
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

from tap_bench.bench.scores.gap import behaviour_gap
from tap_bench.stats.bootstrap import BootstrapConfig

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


WOMD_FILES = ("../shared/data/womd/motion_data_one_scenario.tfrecord",
              "../shared/data/womd/motion_data_one_example.tfrecord",
              "../shared/data/womd/womd_scenario_input.tfrecord",
              "../shared/data/womd/sd_waymo_v1.2_eb4b91b10ca94ff2.pkl",
              "../shared/data/womd-dev/dev.tfrecord")


def real_scene_labels(root: Path) -> pd.DataFrame | None:
    """The vehicles of the real WOMD scenes beside the checkout ``root`` (``WOMD_FILES``
    are relative to it) labelled at the maneuver level
    with their interactions (one row per labelled segment, ``scenario_id`` its scene); None
    when the data is absent."""
    import warnings

    from tap_bench.bench.scores.gap import labelled_with_speed
    from tap_bench.sources import read_womd

    files = [root / f for f in WOMD_FILES if (root / f).exists()]
    if not files:
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        traj = read_womd([str(f) for f in files])
        labels = labelled_with_speed(traj, "maneuver", interactions="all")
    labels = labels[labels["object_type"].astype(str) == "vehicle"]
    return labels.dropna(subset=list(AXES)).assign(mean_speed=np.nan).reset_index(drop=True)


def left_twice() -> dict[str, np.ndarray]:
    """The reference's distributions with ``Left Turn`` twice as likely (0.05 -> 0.10), the
    other lateral labels scaled down to make room."""
    out = {a: np.array(p, float) for a, (_, p) in AXES.items()}
    lat = out["lateral"]
    j = AXES["lateral"][0].index("Left Turn")
    rest = np.arange(len(lat)) != j
    lat[rest] *= (1 - 2 * lat[j]) / lat[rest].sum()
    lat[j] *= 2
    return out


def scenes(p: dict[str, np.ndarray], n_scenes: int, rng: np.random.Generator, *,
           kappa: float, vehicles: float, prefix: str) -> pd.DataFrame:
    """Labels of ``n_scenes`` synthetic scenes with scene random effects: scene s draws
    its label probabilities per axis from Dirichlet(kappa p), its 1 + Poisson(vehicles)
    vehicles draw their labels from them. ``scenario_id`` ``<prefix><s>``."""
    sizes = 1 + rng.poisson(vehicles, n_scenes)
    scene = np.repeat(np.arange(n_scenes), sizes)
    cols = {"scenario_id": np.array([f"{prefix}{s}" for s in scene], object)}
    for axis, (names, _) in AXES.items():
        probs = rng.dirichlet(kappa * p[axis], n_scenes)  # (scenes, K)
        cum = probs.cumsum(axis=1)[scene]
        pick = (rng.random(len(scene))[:, None] > cum).sum(axis=1)
        cols[axis] = np.array(names, object)[np.minimum(pick, len(names) - 1)]
    return pd.DataFrame(cols).assign(mean_speed=np.nan)


def scene_study(args: argparse.Namespace) -> None:
    """The "scenes" cases (module docstring): real scenes split at random, synthetic scenes
    with scene effects, under the null and against a policy turning left twice as often."""
    import tap_bench

    reference = {a: np.array(p, float) for a, (_, p) in AXES.items()}
    shifted = left_twice()
    rows = []
    start, cpu = time.perf_counter(), time.process_time()

    def run(case: str, truth: float, draw, per_side: str, left_truth: float = 0.0) -> None:
        holds = excludes_zero = left_holds = left_excludes = 0
        gaps, lows, highs = [], [], []
        for rep in range(args.replications):
            pol, ref = draw(rep)
            res = behaviour_gap(pol, ref, min_speed=-np.inf, max_speed=np.inf,
                                config=BootstrapConfig(n_resamples=args.resamples,
                                                       seed=rep))
            holds += res.debiased_low - 1e-12 <= truth <= res.debiased_high + 1e-12
            excludes_zero += res.debiased_low > 0
            left = res.labels[(res.labels["axis"] == "lateral")
                              & (res.labels["label"] == "Left Turn")]
            lo, hi = (left["diff_low"].iloc[0], left["diff_high"].iloc[0]) if len(left) \
                else (0.0, 0.0)
            left_holds += lo - 1e-12 <= left_truth <= hi + 1e-12
            left_excludes += lo > 0 or hi < 0
            gaps.append(res.gap_debiased)
            lows.append(res.debiased_low)
            highs.append(res.debiased_high)
        n = args.replications
        rows.append({"case": case, "per_side": per_side, "true_gap": round(truth, 4),
                     "replications": n, "coverage": holds / n,
                     "excludes_0": excludes_zero / n,
                     "mean_debiased": float(np.mean(gaps)),
                     "mean_width": float(np.mean(np.subtract(highs, lows))),
                     "left_turn_true_diff": round(left_truth, 4),
                     "left_turn_coverage": left_holds / n,
                     "left_turn_excludes_0": left_excludes / n})
        print(rows[-1], flush=True)

    real = None if args.skip_real else real_scene_labels(Path(__file__).resolve().parents[1])
    if real is not None:
        ids = np.array(sorted(real["scenario_id"].unique()), object)
        split_rng = np.random.default_rng(38)

        def real_split(rep: int) -> tuple[pd.DataFrame, pd.DataFrame]:
            first = set(split_rng.permutation(ids)[:len(ids) // 2])
            mine = real["scenario_id"].isin(first).to_numpy()
            return real[mine], real[~mine]

        run("real WOMD scenes split in halves (null)", 0.0, real_split,
            f"{len(ids) // 2} scenes, {len(real)} vehicles in all")
    rng = np.random.default_rng(3800)
    for per_side in args.scenes:
        def null(rep: int, per_side=per_side):
            return (scenes(reference, per_side, rng, kappa=args.kappa,
                           vehicles=args.vehicles, prefix="p"),
                    scenes(reference, per_side, rng, kappa=args.kappa,
                           vehicles=args.vehicles, prefix="r"))

        def left(rep: int, per_side=per_side):
            return (scenes(shifted, per_side, rng, kappa=args.kappa,
                           vehicles=args.vehicles, prefix="p"),
                    scenes(reference, per_side, rng, kappa=args.kappa,
                           vehicles=args.vehicles, prefix="r"))

        run("synthetic scenes, same behaviour (null)", 0.0, null, f"{per_side} scenes")
        j = AXES["lateral"][0].index("Left Turn")
        run("synthetic scenes, policy turns left twice as often", _true_gap(shifted,
                                                                            reference),
            left, f"{per_side} scenes",
            left_truth=float(shifted["lateral"][j] - reference["lateral"][j]) / len(AXES))
    print()
    print("| case | per side | true gap | gap's interval holds it | excludes 0 | mean "
          "debiased gap | mean width | Left Turn share diff | its interval holds it | "
          "excludes 0 |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['case']} | {r['per_side']} | {r['true_gap']:.3f} | {r['coverage']:.3f} "
              f"| {r['excludes_0']:.3f} | {r['mean_debiased']:.3f} | {r['mean_width']:.3f} "
              f"| {r['left_turn_true_diff']:+.3f} | {r['left_turn_coverage']:.3f} "
              f"| {r['left_turn_excludes_0']:.3f} |")
    report(f"gap_coverage_scenes_{args.tag}", {
        "rows": rows, "wall_s": round(time.perf_counter() - start, 1),
        "cpu_s": round(time.process_time() - cpu, 1), "replications": args.replications,
        "resamples": args.resamples, "kappa": args.kappa, "vehicles": args.vehicles,
        "tap_bench": str(Path(tap_bench.__file__).parent)}, seed=3800)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--replications", type=int, default=300)
    parser.add_argument("--only", choices=("all", "windows", "scenes"), default="all")
    parser.add_argument("--resamples", type=int, default=1000,
                        help="bootstrap resamples of the scenes cases (1000)")
    parser.add_argument("--scenes", type=int, nargs="+", default=[8, 20, 50, 150],
                        help="synthetic scenes per side (8 20 50 150)")
    parser.add_argument("--kappa", type=float, default=5.0,
                        help="Dirichlet concentration of the scene effects (5)")
    parser.add_argument("--vehicles", type=float, default=30.0,
                        help="mean vehicles per synthetic scene, less 1 (30)")
    parser.add_argument("--skip-real", action="store_true", help="synthetic scenes only")
    parser.add_argument("--tag", default="now", help="names the scenes output file")
    args = parser.parse_args()
    if args.only == "scenes":
        scene_study(args)
        return
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
