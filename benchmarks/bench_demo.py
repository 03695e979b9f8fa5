"""``tap-bench demo`` with this code and with an older commit, in one run: wall and CPU of
each phase for both, and whether both gave the same episodes and crashes.

The older commit is checked out in a temporary git worktree (removed at the end). Each
version runs the demo in a fresh process with an empty episode cache, twice per repeat:
once as usual (wall seconds per phase, as the run records them in ``summary.json``) and
once with ``time.perf_counter`` replaced by ``time.process_time`` in the run's process and
in each of its worker processes (a ``sitecustomize`` on the ``PYTHONPATH``), so that the
same records hold CPU seconds (user + sys) per phase; the versions need no change for it.
Totals are measured from outside: wall, and CPU of the run and all its workers
(``RUSAGE_CHILDREN``). The versions alternate, so a change of the machine's load hits both.
Both versions must simulate the same episodes: their episode tables (status, crashes,
lengths, returns) and trajectory tables (every vehicle's state at every step, on the
columns both write, floats within 1e-6) are compared.

Phases: ``rollouts`` (simulating, in the workers), ``labelling`` and ``measures`` (TAP and
the per-episode measures, in the workers or in the run's process, whichever the version
does), ``scoring``, ``report`` (tables, figures, HTML and viewer), ``total``.

``--first-run`` measures instead what a new user measures: the demo as the README runs it
(``tap-bench demo``), once, from a fresh copy of this commit's tree (``git archive``: no
``__pycache__``, so no compiled bytecode and no numba kernels cached beside the code) with
a fresh ``HOME`` (no ``~/.cache/tap-bench`` episodes or highway-env schema, no matplotlib
font cache), then a second run in the same ``HOME`` and tree (caches warm, a new output
folder) for comparison. Wall, and CPU of the run and its workers.

Usage::

    python benchmarks/bench_demo.py [--old 4e8674d] [--repeats 1] [--workers 2]
    python benchmarks/bench_demo.py --first-run
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from machine import report

ROOT = Path(__file__).resolve().parents[1]

PHASES = {
    # phase: the keys of summary["timings"] that hold it (whichever the version records)
    "rollouts": ("rollout_cpu_in_workers",),
    "labelling": ("labelling_cpu_in_workers", "labelling"),
    "measures": ("measures_cpu_in_workers", "measures"),
    "scoring": ("scoring",),
    "report": ("writing_and_report",),
}
"""Where each phase's time is in a run's summary.json."""

SITECUSTOMIZE = """\
import os
import time

if os.environ.get("TAP_BENCH_BENCH_CLOCK") == "cpu":
    time.perf_counter = time.process_time  # the run's own records become CPU seconds
"""

DRIVER = """\
import sys
from tap_bench.cli import main
sys.exit(main(["demo", "-o", sys.argv[1], "--workers", sys.argv[2], "--no-progress"]))
"""


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_demo(tree: Path, clock: str, workers: int, scratch: Path, hook: Path
             ) -> tuple[dict[str, float], tuple[pd.DataFrame, pd.DataFrame | None]]:
    """One demo run of the code in ``tree``: its phases [s] on ``clock`` (wall or cpu), its
    total wall and CPU [s], and its episode and trajectory tables (None: not written)."""
    out = Path(tempfile.mkdtemp(prefix="demo-", dir=scratch)) / "run"  # new: never replaced
    cache = Path(tempfile.mkdtemp(prefix="cache-", dir=scratch))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(hook), str(tree)]),
           "TAP_BENCH_CACHE": str(cache), "OMP_WAIT_POLICY": "PASSIVE",
           "TAP_BENCH_BENCH_CLOCK": clock}
    cpu0, wall0 = _children_cpu(), time.perf_counter()
    done = subprocess.run([sys.executable, "-c", DRIVER, str(out), str(workers)], env=env,
                          cwd=scratch, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - wall0, _children_cpu() - cpu0
    if done.returncode:
        raise SystemExit(f"the demo of {tree} failed ({done.returncode}):\n{done.stderr}")
    timings = json.loads((out / "summary.json").read_text())["timings"]
    phases = {phase: sum(timings.get(k, 0.0) for k in keys) for phase, keys in PHASES.items()}
    phases.update(total_wall=wall, total_cpu=cpu)
    trajectories = out / "trajectories.parquet"
    return phases, (pd.read_parquet(out / "episodes.parquet"),
                    pd.read_parquet(trajectories) if trajectories.exists() else None)


def _same_episodes(a: pd.DataFrame, b: pd.DataFrame) -> dict[str, object]:
    """Whether two demo runs simulated the same episodes: the same (env, policy, seed)
    with the same status, crashes, lengths and returns."""
    keys = ["env", "policy", "seed"]
    cols = [c for c in ("status", "crashed", "length", "terminated", "truncated", "return")
            if c in a.columns and c in b.columns]
    x = a[keys + cols].sort_values(keys).reset_index(drop=True)
    y = b[keys + cols].sort_values(keys).reset_index(drop=True)
    floats = [c for c in cols if c == "return"]
    exact = [c for c in cols if c not in floats]
    same = len(x) == len(y) and x[keys + exact].equals(y[keys + exact]) and all(
        np.allclose(x[c].to_numpy(float), y[c].to_numpy(float), rtol=0, atol=1e-6,
                    equal_nan=True) for c in floats)
    return {"same_episodes_and_crashes": bool(same), "compared": cols,
            "episodes": [len(a), len(b)],
            "crashes": [int(a["crashed"].fillna(False).astype(bool).sum()),
                        int(b["crashed"].fillna(False).astype(bool).sum())]}


def _same_trajectories(a: pd.DataFrame | None, b: pd.DataFrame | None) -> dict[str, object]:
    """Whether two demo runs wrote the same trajectory tables: every vehicle's state at
    every step, on the columns both versions write, floats within 1e-6."""
    if a is None or b is None:
        return {"same_trajectories": None, "trajectory_rows": None}
    keys = [c for c in ("env", "policy", "seed", "track_id", "t") if c in a and c in b]
    state = [c for c in ("x", "y", "heading", "speed", "vx", "vy", "valid", "is_ego",
                         "crashed", "lane", "road") if c in a.columns and c in b.columns]
    x = a[keys + state].sort_values(keys).reset_index(drop=True)
    y = b[keys + state].sort_values(keys).reset_index(drop=True)
    def equal(c: str) -> bool:  # floats within 1e-6 (the traffic core's tolerance)
        u, v = x[c].to_numpy(), y[c].to_numpy()
        if u.dtype.kind == "f" and v.dtype.kind == "f":
            return bool(np.allclose(u, v, rtol=0, atol=1e-6, equal_nan=True))
        return bool(np.array_equal(u, v))

    same = len(x) == len(y) and all(equal(c) for c in keys + state)
    return {"same_trajectories": bool(same), "trajectory_rows": [len(a), len(b)],
            "trajectory_columns_compared": state}


def first_run() -> None:
    """The demo as a new user runs it first (see the module docstring), then again."""
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                          check=True, capture_output=True, text=True).stdout.strip()
    with tempfile.TemporaryDirectory(prefix="bench-demo-first-") as tmp:
        scratch = Path(tmp)
        tree, home = scratch / "tap-bench", scratch / "home"
        tree.mkdir()
        home.mkdir()
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", "HEAD"], check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
        shared = ROOT.parent / "shared"
        if shared.is_dir():  # beside the copy as beside a checkout (the README's layout)
            (scratch / "shared").symlink_to(shared)
        drop = ("TAP_BENCH_CACHE", "TAP_BENCH_PATH", "TAP_BENCH_SUITE", "XDG_CACHE_HOME",
                "MPLCONFIGDIR", "NUMBA_CACHE_DIR", "PYTHONDONTWRITEBYTECODE")
        env = {**{k: v for k, v in os.environ.items() if k not in drop},
               "HOME": str(home), "PYTHONPATH": str(tree)}
        runs = {}
        for name in ("first", "second"):
            cpu0, wall0 = _children_cpu(), time.perf_counter()
            done = subprocess.run([sys.executable, "-m", "tap_bench", "demo", "-o",
                                   str(scratch / f"demo-{name}"), "--no-progress"],
                                  env=env, cwd=tree, capture_output=True, text=True)
            wall, cpu = time.perf_counter() - wall0, _children_cpu() - cpu0
            if done.returncode:
                raise SystemExit(f"the demo failed ({done.returncode}):\n{done.stderr}")
            runs[name] = {"wall_s": round(wall, 2), "cpu_s": round(cpu, 2),
                          "load_after": round(os.getloadavg()[0], 2)}
            print(f"{name} run: {wall:.1f} s wall, {cpu:.1f} CPU s (user + sys, workers "
                  f"included), load {os.getloadavg()[0]:.1f}", file=sys.stderr, flush=True)
    report("demo_first_run", {"commit": head, **runs},
           note="first: a fresh copy of the tree (no __pycache__, no numba cache) and a "
                "fresh HOME (no caches); second: the same tree and HOME again")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--old", default="4e8674d", help="the older commit (default 4e8674d)")
    parser.add_argument("--repeats", type=int, default=1, help="runs per version and clock")
    parser.add_argument("--workers", type=int, default=2, help="demo --workers (2)")
    parser.add_argument("--first-run", action="store_true",
                        help="measure a new user's first run of the demo instead")
    args = parser.parse_args()
    if args.first_run:
        first_run()
        return

    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", args.old],
                            check=True, capture_output=True, text=True).stdout.strip()
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                          check=True, capture_output=True, text=True).stdout.strip()
    with tempfile.TemporaryDirectory(prefix="bench-demo-") as tmp:
        scratch = Path(tmp)
        hook = scratch / "hook"
        hook.mkdir()
        (hook / "sitecustomize.py").write_text(SITECUSTOMIZE)
        old_tree = scratch / "old"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", "--quiet",
                        str(old_tree), commit], check=True)
        try:
            runs: dict[str, dict[str, list[dict[str, float]]]] = {
                "this": {"wall": [], "cpu": []}, "old": {"wall": [], "cpu": []}}
            episodes: dict[str, pd.DataFrame] = {}
            trajectories: dict[str, pd.DataFrame | None] = {}
            for repeat in range(args.repeats):
                for clock in ("wall", "cpu"):
                    for name, tree in (("old", old_tree), ("this", ROOT)):
                        phases, (eps, tracks) = run_demo(tree, clock, args.workers,
                                                         scratch, hook)
                        runs[name][clock].append(phases)
                        episodes[name], trajectories[name] = eps, tracks
                        print(f"repeat {repeat + 1}, {clock} clock, {name}: "
                              + ", ".join(f"{k} {v:.2f}" for k, v in phases.items()),
                              file=sys.stderr, flush=True)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force",
                            str(old_tree)], check=False)

    def median(name: str, clock: str, phase: str) -> float:
        return statistics.median(r[phase] for r in runs[name][clock])

    table = {}
    for phase in [*PHASES, "total"]:
        row = {}
        for name in ("old", "this"):
            if phase == "total":  # measured from outside: wall and CPU of the same runs
                wall = statistics.median(r["total_wall"] for r in runs[name]["wall"])
                cpu = statistics.median(r["total_cpu"] for r in runs[name]["wall"]
                                        + runs[name]["cpu"])
            else:
                wall, cpu = median(name, "wall", phase), median(name, "cpu", phase)
            row[f"{name}_wall_s"], row[f"{name}_cpu_s"] = round(wall, 2), round(cpu, 2)
        row["cpu_ratio_this_over_old"] = (round(row["this_cpu_s"] / row["old_cpu_s"], 3)
                                          if row["old_cpu_s"] > 0 else None)
        table[phase] = row
    print(f"\n{'phase':10s} {'old wall':>9s} {'old cpu':>8s} {'this wall':>10s} "
          f"{'this cpu':>9s} {'cpu this/old':>13s}")
    for phase, row in table.items():
        ratio = row["cpu_ratio_this_over_old"]
        print(f"{phase:10s} {row['old_wall_s']:9.2f} {row['old_cpu_s']:8.2f} "
              f"{row['this_wall_s']:10.2f} {row['this_cpu_s']:9.2f} "
              f"{ratio if ratio is not None else float('nan'):13.3f}")
    report("demo_before_after", {
        "old_commit": commit, "this_commit": head, "phases": table,
        **_same_episodes(episodes["old"], episodes["this"]),
        **_same_trajectories(trajectories["old"], trajectories["this"]),
    }, repeats=args.repeats, workers=args.workers,
        note="phases: median over repeats; cpu = user + sys of the run and its workers "
             "(phases from the run's own records on a CPU clock, total from RUSAGE_CHILDREN)")


if __name__ == "__main__":
    main()
