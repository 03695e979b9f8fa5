"""Re-runs that redo nothing (issue 24 section 3): the CPU of an unchanged re-run of a suite
against its first run, both as a user runs them (``tap-bench bench run`` in a child
process, start-up, workers, scoring, the report and the viewer included).

The first run starts from an empty episode cache (a fresh folder); the re-run uses the same
cache unchanged: the whole run is served from its run entry
(``tap_bench/bench/run/served.py``), or, with ``--without-run-entry`` (the entry deleted
before each re-run), its episodes and their labels and measures are read, so scoring and
the report are its only work. CPU is user + sys of the command and every process it
started (``RUSAGE_CHILDREN``); wall time beside it; the machine's load is printed (the
machine is shared). The script checks that the re-run's tables equal the first run's,
floats with ``==``.

Targets: an unchanged re-run of a 24-episode suite (2 envs x 2 policies x 6 seeds) costs
<= 10 % of its first run's CPU; of the default suite (750 episodes) <= 3 %.

tap-bench's bytecode is compiled first (``compileall``), as ``pip install`` leaves a package;
``--as-checked-out`` measures without that, where ``PYTHONDONTWRITEBYTECODE`` makes every
process compile what it imports.

Usage: ``nice -n 10 python benchmarks/bench_rerun.py [--suite small|default|FILE]
[--workers 2] [--repeat 1] [--without-run-entry] [--as-checked-out]``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
from machine import describe_machine, report

ROOT = Path(__file__).resolve().parents[1]

SMALL = {"name": "small24", "version": 0,
         "description": "2 envs x 2 policies x 6 seeds (issue 24 section 3)",
         "envs": ["highway", "merge"], "policies": ["idm", "lane-keeping"], "seeds": "0-5",
         "reference_policy": "idm", "level": "maneuver", "thresholds": "paper"}


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def timed_cli(args: list[str], env: dict[str, str]) -> dict[str, float]:
    """Run ``python -m tap_bench ARGS``; its wall and CPU (with every process it started)."""
    cpu0, wall0 = _children_cpu(), time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "tap_bench", *args], env=env,
                          capture_output=True, text=True)
    wall, cpu = time.perf_counter() - wall0, _children_cpu() - cpu0
    if done.returncode != 0:
        raise SystemExit(f"tap-bench {' '.join(args)} failed:\n{done.stderr}")
    return {"wall_s": round(wall, 2), "cpu_s": round(cpu, 2),
            "load_1m": round(os.getloadavg()[0], 2)}


def same_tables(a: Path, b: Path) -> list[str]:
    """The tables of run folder ``a`` that differ from ``b``'s (floats compared with ==)."""
    differ = []
    for path in sorted(a.glob("*.parquet")):
        left, right = pd.read_parquet(path), pd.read_parquet(b / path.name)
        try:
            pd.testing.assert_frame_equal(left, right, check_exact=True)
        except AssertionError:
            differ.append(path.name)
    return differ


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--suite", default="small",
                        help="small (2 envs x 2 policies x 6 seeds), default, or a suite file")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=1, help="re-runs timed (the median)")
    parser.add_argument("--as-checked-out", action="store_true",
                        help="do not compile tap-bench's bytecode first: where "
                        "PYTHONDONTWRITEBYTECODE is set, every process then compiles the "
                        "modules it imports (about 0.06 CPU s a process)")
    parser.add_argument("--without-run-entry", action="store_true",
                        help="delete the whole run's cache entry before each re-run (the "
                        "re-run then reads each episode's labels and measures)")
    args = parser.parse_args()
    if not args.as_checked_out:  # as `pip install` leaves a package: its bytecode compiled
        subprocess.run([sys.executable, "-m", "compileall", "-q", str(ROOT / "tap_bench")],
                       check=True)
    with tempfile.TemporaryDirectory(prefix="bench-rerun-") as tmp:
        tmp = Path(tmp)
        if args.suite == "small":
            suite = tmp / "small24.json"
            suite.write_text(json.dumps(SMALL))
        else:
            suite = args.suite
        env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}"
               f"{os.environ.get('PYTHONPATH', '')}", "OMP_WAIT_POLICY": "PASSIVE",
               "TAP_BENCH_CACHE": str(tmp / "cache")}
        common = ["bench", "run", "--suite", str(suite), "--workers", str(args.workers),
                  "--no-progress"]
        machine = describe_machine()
        print(f"machine: {machine['cpu']}, {machine['cores']} cores, load "
              f"{machine['load_avg_1m']} (shared)")
        first = timed_cli([*common, "-o", str(tmp / "first")], env)
        print(f"first run: {first}")
        reruns = []
        for i in range(args.repeat):
            if args.without_run_entry:
                shutil.rmtree(tmp / "cache" / "derived" / "runs", ignore_errors=True)
            reruns.append(timed_cli([*common, "-o", str(tmp / f"rerun{i}")], env))
            print(f"re-run {i + 1}: {reruns[-1]}")
        rerun = sorted(reruns, key=lambda r: r["cpu_s"])[len(reruns) // 2]
        summary = json.loads((tmp / "rerun0" / "summary.json").read_text())
        differ = same_tables(tmp / "first", tmp / "rerun0")
        figures = {
            "suite": str(args.suite), "episodes": summary["n_episodes"],
            "first_cpu_s": first["cpu_s"], "first_wall_s": first["wall_s"],
            "rerun_cpu_s": rerun["cpu_s"], "rerun_wall_s": rerun["wall_s"],
            "rerun_cpu_share": round(rerun["cpu_s"] / first["cpu_s"], 4),
            "rerun_wall_share": round(rerun["wall_s"] / first["wall_s"], 4),
            "rerun_cache": summary["cache"], "rerun_timings": summary["timings"],
            "tables_differing": differ, "load_1m": [first["load_1m"], rerun["load_1m"]],
        }
        figures["run_entry"] = not args.without_run_entry
        figures["bytecode"] = "as checked out" if args.as_checked_out else \
            "compiled first (compileall), as pip installs a package"
        name = f"rerun_{Path(str(args.suite)).stem}" + (
            "_without_run_entry" if args.without_run_entry else "")
        report(name, figures, workers=args.workers)
        if differ:
            raise SystemExit(f"the re-run's tables differ from the first run's: {differ}")


if __name__ == "__main__":
    main()
