"""The regression gate's false alarms and power on real rollouts, and the choice of its
multiplicity correction.

    PYTHONPATH=$PWD python benchmarks/gate_calibration.py [--workers 2] [--rerun]
        [--suite-runs RUN_0_29 RUN_30_59] [--reps 100]

**Rollouts** (highway, 10 vehicles, shortened to 12 s; cached in
``benchmarks/out/gate_calibration_episodes.parquet``, ``--rerun`` redoes them): IDM/MOBIL
(highway-env's defaults) and lane keeping (never brakes for a leader: it crashes often)
on seeds 0-299; IDM with a 10 % lower desired speed and with a 2.5 s time gap on seeds
0-99.

**A policy with a crash rate of about q**: on each seed it drives as lane keeping when
u < q' and as IDM otherwise (u uniform per seed, q' = (q - c_idm) / (c_lk - c_idm) from
the two policies' crash rates), i.e. a policy that on some episodes stops reacting to its
leader. Its episodes are real rollouts. The baseline is q = 0.05, the regression q = 0.30:
**a crash-rate rise of 25 points from 5 %**. Paired (the baseline's seeds): the same u per
seed for both (a seeded policy keeps its random stream: the run's lane-keeping seeds
include the baseline's); "independent" draws the run's u afresh (the worst case for a
paired test). Each replicate draws new u's; blocks of 30 seeds.

**Checks** (the gate's default settings: alpha 0.05, 9999 permutations, margins):

1. false alarms, one cell: the q = 0.05 policy against itself on other seeds (unpaired);
2. power, one cell: q = 0.05 -> 0.30 on the same seeds (paired; nested and independent
   u) and on other seeds (unpaired);
3. the default suite (``--suite-runs``: two runs of ``bench run --suite default``, seeds
   0-29 and 30-59): its 25 cells with the highway/idm cell replaced by the mixture policy.
   False alarms: the 60 seeds of every cell split at random into two halves of 30
   (unpaired, as a check on fresh seeds is); power: the regression in that one cell, the
   other 24 cells re-run unchanged (paired: identical episodes) or on fresh seeds;
4. IDM's desired speed 10 % lower and its time gap 2.5 s (paired, blocks of 30).

Every check is decided by each candidate multiplicity procedure from the same p-values:
Holm over every test (equal weights); the same with Tarone's reduction (tests that cannot
reach their share of alpha left out); the safety family first (0.8 of alpha shared
equally by crash rate, TTC and headway, with Tarone); crash-first weights (crash 0.6,
TTC 0.1, headway 0.1, the rest 0.2; and the gate's default: crash 0.65, TTC 0.1, headway
0.1, the rest 0.15; with Tarone); Benjamini-Hochberg
(false discovery rate 0.05, equal weights). The figures: the share of checks that fail
(any metric the worse way) and that fail on the crash rate, with Wilson intervals.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import report

from tap_bench.bench.episodes import episode_table
from tap_bench.bench.gate.regression import check, direction, weighted_holm
from tap_bench.bench.measures import MEASURES
from tap_bench.bench.suite import GateConfig, gate_metrics
from tap_bench.stats.intervals import wilson_interval

OUT = Path(__file__).resolve().parent / "out"
CACHE = OUT / "gate_calibration_episodes.parquet"
ENV = "highway"
DURATION = 12.0  # [s]
CONFIG = {"vehicles_count": 10}
POOL = 300
CHANGED_SEEDS = 100
BLOCK = 30
IDM = {"time_wanted": 1.5, "distance_wanted": 10.0, "comfort_acc_max": 3.0,
       "comfort_acc_min": -5.0, "delta": 4.0, "politeness": 0.0,
       "lane_change_min_acc_gain": 0.2, "lane_change_max_braking_imposed": 2.0,
       "lane_change_delay": 1.0, "target_speed_factor": 1.0}
CHANGES = {"idm-speed-0.9": {"target_speed_factor": 0.9}, "idm-gap-2.5s": {"time_wanted": 2.5}}
BASE_RATE, RAISED_RATE = 0.05, 0.30
SUMMARY = {"suite": {"name": "gate-calibration", "version": 0}, "level": "maneuver",
           "thresholds": "paper"}
BASELINE = {"suite": "gate-calibration", "suite_version": 0, "level": "maneuver",
            "thresholds": "paper"}


def _episodes(name: str, kind: str, params: dict, seeds: list[int], workers: int
              ) -> pd.DataFrame:
    from tap_bench.labelling import tap
    from tap_bench.sim.policies import PolicyDefinition
    from tap_bench.sim.rollout import rollout

    policy = PolicyDefinition(name=name, kind=kind, params=params)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = rollout(ENV, policy, seeds, workers=workers, config=CONFIG,
                         duration=DURATION, progress=False)
        labels = tap(result.trajectories, "paper").labels("all")
    return episode_table(labels=labels, trajectories=result.trajectories,
                         episodes=result.episodes, level="maneuver", policy=name)


def rollouts(workers: int, rerun: bool) -> tuple[pd.DataFrame, float]:
    if CACHE.is_file() and not rerun:
        return pd.read_parquet(CACHE), 0.0
    start = time.perf_counter()
    frames = []
    for name, kind, params, n in (("idm", "idm", IDM, POOL),
                                  ("lane-keeping", "lane_keeping", {}, POOL),
                                  *((k, "idm", {**IDM, **v}, CHANGED_SEEDS)
                                    for k, v in CHANGES.items())):
        t0 = time.perf_counter()
        frames.append(_episodes(name, kind, params, list(range(n)), workers))
        print(f"rollouts: {name}, {n} seeds, {time.perf_counter() - t0:.0f} s", flush=True)
    table = pd.concat(frames, ignore_index=True)
    OUT.mkdir(exist_ok=True)
    table.to_parquet(CACHE, index=False)
    return table, time.perf_counter() - start


# --- the candidate multiplicity procedures -------------------------------------------

def _bh(p: np.ndarray) -> np.ndarray:
    m = len(p)
    order = np.argsort(p)
    adj = np.minimum.accumulate((p[order] * m / np.arange(1, m + 1))[::-1])[::-1]
    out = np.empty(m)
    out[order] = np.minimum(adj, 1.0)
    return out


def _weights(table: pd.DataFrame, shares: dict[str, float] | None) -> np.ndarray:
    metrics = gate_metrics()
    if shares is None:
        return np.ones(len(table))
    rest = [m for m in metrics if m not in shares]
    left = 1.0 - sum(shares.values())
    full = {**shares, **{m: left / len(rest) for m in rest}}
    return table["metric"].map(full).to_numpy(float)


PROCEDURES = {
    "Holm, all tests": (None, False, "holm"),
    "Holm + Tarone": (None, True, "holm"),
    "safety family 0.8, Tarone": ({"crashed": 0.8 / 3, "min_ttc_s": 0.8 / 3,
                                   "min_headway_s": 0.8 / 3}, True, "holm"),
    "crash-first 0.6, Tarone": ({"crashed": 0.6, "min_ttc_s": 0.1, "min_headway_s": 0.1},
                                True, "holm"),
    "crash-first 0.65 (default), Tarone": ({m.name: m.gate_weight for m in MEASURES
                                            if m.gate_weight is not None}, True, "holm"),
    "BH (FDR), all tests": (None, False, "bh"),
}


def decide(table: pd.DataFrame, alpha: float = 0.05) -> dict[str, tuple[bool, bool]]:
    """procedure -> (the check fails, it fails on the crash rate), from the raw p-values."""
    t = table[table["p_value"].notna()]
    p = t["p_value"].to_numpy(float)
    sign = t["metric"].map(direction).to_numpy(float)
    change = t["change"].to_numpy(float)
    worse_by = np.where(sign == 0, change, -sign * change)
    beyond = worse_by > t["margin"].to_numpy(float)
    crash = (t["metric"] == "crashed").to_numpy()
    out = {}
    for name, (shares, tarone, kind) in PROCEDURES.items():
        if kind == "bh":
            adj = _bh(p)
        else:
            adj = weighted_holm(p, _weights(t, shares),
                                t["p_min"].to_numpy(float) if tarone else None, alpha)
        fail = (adj < alpha) & beyond
        out[name] = (bool(fail.any()), bool((fail & crash).any()))
    return out


def _mixture(idm: pd.DataFrame, lk: pd.DataFrame, seeds: np.ndarray, u: np.ndarray,
             share: float) -> pd.DataFrame:
    """The mixture policy's episodes on ``seeds``: lane keeping where u < share."""
    a = idm.set_index("seed").loc[seeds]
    b = lk.set_index("seed").loc[seeds]
    pick = u < share
    out = pd.concat([a[~pick], b[pick]]).loc[seeds].reset_index()
    return out.assign(policy="mixture", env=ENV)


class Tally:
    """Per (study, procedure): checks, fails, fails on the crash rate."""

    def __init__(self) -> None:
        self.rows: dict[tuple[str, str], list[int]] = {}

    def add(self, study: str, decisions: dict[str, tuple[bool, bool]]) -> None:
        for proc, (fail, crash) in decisions.items():
            r = self.rows.setdefault((study, proc), [0, 0, 0])
            r[0] += 1
            r[1] += fail
            r[2] += crash

    def table(self) -> pd.DataFrame:
        rows = []
        for (study, proc), (n, fail, crash) in self.rows.items():
            lo, hi = wilson_interval(fail, n, 0.95)
            clo, chi = wilson_interval(crash, n, 0.95)
            rows.append({"study": study, "procedure": proc, "checks": n,
                         "fails": fail / n, "fails_low": lo, "fails_high": hi,
                         "fails_on_crash": crash / n, "crash_low": clo, "crash_high": chi})
        return pd.DataFrame(rows)


def _suite_cells(run_a: Path, run_b: Path) -> pd.DataFrame:
    frames = []
    for folder in (run_a, run_b):
        eps = pd.read_parquet(folder / "episodes.parquet")
        frames.append(eps[eps["status"] == "ok"])
    return pd.concat(frames, ignore_index=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--rerun", action="store_true", help="redo the cached rollouts")
    parser.add_argument("--reps", type=int, default=100, help="replicates per study")
    parser.add_argument("--suite-runs", nargs=2, type=Path, metavar=("RUN_0_29", "RUN_30_59"),
                        help="two default-suite runs (seeds 0-29 and 30-59)")
    parser.add_argument("--skip-policy", action="append", default=[],
                        help="leave this policy's cells of the suite runs out (one whose "
                        "definition differs between the two runs)")
    args = parser.parse_args()
    episodes, rollout_seconds = rollouts(args.workers, args.rerun)
    start = time.perf_counter()
    cpu0 = time.process_time()
    gate = GateConfig()
    idm = episodes[episodes["policy"] == "idm"].sort_values("seed")
    lk = episodes[episodes["policy"] == "lane-keeping"].sort_values("seed")
    c_idm, c_lk = float(idm["crashed"].mean()), float(lk["crashed"].mean())
    share = {q: (q - c_idm) / (c_lk - c_idm) for q in (BASE_RATE, RAISED_RATE)}
    print(f"crash rates: idm {c_idm:.3f}, lane keeping {c_lk:.3f}; lane-keeping shares "
          f"{share[BASE_RATE]:.3f} (q 0.05), {share[RAISED_RATE]:.3f} (q 0.30)", flush=True)
    tally = Tally()
    rates = {"base": [], "raised": []}
    rng = np.random.default_rng(25)
    blocks = [np.arange(k * BLOCK, (k + 1) * BLOCK) for k in range(POOL // BLOCK)]

    def run_check(run: pd.DataFrame, base: pd.DataFrame) -> dict:
        result = check(SUMMARY, run, BASELINE, base, gate, power=False)
        return decide(result.table)

    for rep in range(args.reps):
        u = rng.random(POOL)
        u_fresh = rng.random(POOL)
        i, j = rng.choice(len(blocks), 2, replace=False)
        base = _mixture(idm, lk, blocks[i], u[blocks[i]], share[BASE_RATE])
        other = _mixture(idm, lk, blocks[j], u[blocks[j]], share[BASE_RATE])
        nested = _mixture(idm, lk, blocks[i], u[blocks[i]], share[RAISED_RATE])
        indep = _mixture(idm, lk, blocks[i], u_fresh[blocks[i]], share[RAISED_RATE])
        fresh = _mixture(idm, lk, blocks[j], u[blocks[j]], share[RAISED_RATE])
        rates["base"].append(base["crashed"].mean())
        rates["raised"].append(nested["crashed"].mean())
        tally.add("1 one cell: unchanged, other seeds (false alarm)", run_check(other, base))
        tally.add("2 one cell: +25 pts, same seeds, nested (power)", run_check(nested, base))
        tally.add("2 one cell: +25 pts, same seeds, independent (power)",
                  run_check(indep, base))
        tally.add("2 one cell: +25 pts, other seeds (power)", run_check(fresh, base))
        if rep % 10 == 9:
            print(f"  {rep + 1} of {args.reps} one-cell replicates", flush=True)

    for name in CHANGES:
        changed = episodes[episodes["policy"] == name]
        for k in range(CHANGED_SEEDS // BLOCK):
            seeds = np.arange(k * BLOCK, (k + 1) * BLOCK)
            base = idm[idm["seed"].isin(seeds)].assign(policy="idm")
            run = changed[changed["seed"].isin(seeds)].assign(policy="idm")
            tally.add(f"4 IDM {name}, same seeds (power)", run_check(run, base))

    suite_seconds = 0.0
    if args.suite_runs:
        t0 = time.perf_counter()
        cells = _suite_cells(*args.suite_runs)
        cells = cells[~((cells["env"] == ENV) & (cells["policy"] == "idm"))
                      & ~cells["policy"].isin(args.skip_policy)]
        n_suite_cells = len(cells[["env", "policy"]].drop_duplicates()) + 1
        keys = cells[["env", "policy"]].drop_duplicates().to_numpy()
        for rep in range(args.reps):
            u = rng.random(POOL)
            i, j = rng.choice(len(blocks), 2, replace=False)
            base_cell = _mixture(idm, lk, blocks[i], u[blocks[i]], share[BASE_RATE])
            fresh_cell = _mixture(idm, lk, blocks[j], u[blocks[j]], share[BASE_RATE])
            raised = _mixture(idm, lk, blocks[i], u[blocks[i]], share[RAISED_RATE])
            halves_a, halves_b = [], []
            for env, policy in keys:
                sub = cells[(cells["env"] == env) & (cells["policy"] == policy)]
                order = rng.permutation(len(sub))
                half = len(sub) // 2
                halves_a.append(sub.iloc[order[:half]])
                halves_b.append(sub.iloc[order[half:2 * half]])
            a = pd.concat(halves_a, ignore_index=True)
            b = pd.concat(halves_b, ignore_index=True)
            same = cells[cells["seed"] < 30]
            tally.add(f"3 suite of {n_suite_cells} cells: unchanged, other seeds (false alarm)",
                      run_check(pd.concat([b, fresh_cell]), pd.concat([a, base_cell])))
            tally.add(f"3 suite of {n_suite_cells} cells: +25 pts in one cell, same seeds "
                      "(power)",
                      run_check(pd.concat([same, raised]), pd.concat([same, base_cell])))
            if rep % 10 == 9:
                print(f"  {rep + 1} of {args.reps} suite replicates", flush=True)
        suite_seconds = time.perf_counter() - t0

    out = tally.table().sort_values(["study", "procedure"], kind="stable")
    print()
    print(f"crash rates of the mixtures over the replicates: baseline "
          f"{np.mean(rates['base']):.3f}, regression {np.mean(rates['raised']):.3f} "
          f"(30-seed blocks; rollouts {ENV} {DURATION:g} s)")
    print("| study | procedure | checks | fails [95 % Wilson] | fails on the crash rate |")
    print("|---|---|---|---|---|")
    for r in out.itertuples():
        print(f"| {r.study} | {r.procedure} | {r.checks} | {r.fails:.2f} [{r.fails_low:.2f}, "
              f"{r.fails_high:.2f}] | {r.fails_on_crash:.2f} [{r.crash_low:.2f}, "
              f"{r.crash_high:.2f}] |")
    report("gate_calibration", {
        "rows": json.loads(out.to_json(orient="records")), "rollout_seconds": rollout_seconds,
        "check_seconds": time.perf_counter() - start,
        "check_cpu_seconds": time.process_time() - cpu0, "suite_seconds": suite_seconds,
        "crash_rates": {"idm": c_idm, "lane_keeping": c_lk,
                        "baseline_mean": float(np.mean(rates["base"])),
                        "regression_mean": float(np.mean(rates["raised"]))},
        "env": ENV, "duration_s": DURATION, "config": CONFIG, "gate": gate.to_dict(),
        "reps": args.reps, "suite_runs": [str(p) for p in args.suite_runs or []],
        "skipped_policies": args.skip_policy}, seed=25)


if __name__ == "__main__":
    main()
