"""The report phase of a run (issue 24 section 2): the CPU of writing a scored run's tables,
replay viewer, figures and ``report.html`` (``write_results``), as ``bench run`` and
``demo`` pay it, for one or more tap-bench checkouts.

Each measurement is a fresh interpreter with the checkout first on ``PYTHONPATH``: it imports
what a run has imported before its report phase (``tap_bench.bench.run.runner`` and the scoring),
reads the run folder's tables back, then times ``write_results`` into a new folder: CPU
(user + sys of the process, ``time.process_time``) and wall. The first call of a process
pays the imports the report phase makes on its own (matplotlib, before issue 24's port),
which is the figure a run pays; a second call in the same process is given beside it.
The checkouts alternate, so a change of the machine's load hits each; the figures are
medians over ``--repeats``. The machine is shared: read CPU, not wall.

Usage: ``python benchmarks/bench_report.py [RUN_DIR] [--tree DIR ...] [--repeats 5]``
(without RUN_DIR: ``tap-bench demo`` is run first into a temporary folder).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from machine import report

HERE = Path(__file__).resolve().parents[1]

CHILD = """\
import json, sys, time
from pathlib import Path
import pandas as pd
import tap_bench.bench.run.runner  # noqa: F401  (imported by every run before its report)
from tap_bench.bench.run.folder import write_results
from tap_bench.bench.scores.scoring import Scores

run, out = Path(sys.argv[1]), Path(sys.argv[2])
summary = json.loads((run / "summary.json").read_text())
def table(name):
    path = run / f"{name}.parquet"
    return pd.read_parquet(path) if path.is_file() else pd.DataFrame()
scores = Scores(**{name: table(name) for name in Scores.TABLES},
                methods=summary.get("methods", {}))
episodes, labels, trajectories = table("episodes"), table("labels"), table("trajectories")
segments, roads = table("segments"), table("roads")
times = []
for k in range(2):
    c0, w0 = time.process_time(), time.perf_counter()
    write_results(out / f"run{k}", False, summary, episodes, labels, trajectories, scores,
                  segments=segments, roads=roads)
    times.append((time.process_time() - c0, time.perf_counter() - w0))
print(json.dumps(times))
"""


def measure(tree: Path, run: Path) -> tuple[tuple[float, float], tuple[float, float]]:
    """((cpu, wall) of the first write_results of a process, (cpu, wall) of the second)."""
    with tempfile.TemporaryDirectory(prefix="bench-report-") as out:
        env = {**os.environ, "PYTHONPATH": str(tree), "OMP_WAIT_POLICY": "PASSIVE"}
        done = subprocess.run([sys.executable, "-c", CHILD, str(run), out], env=env,
                              capture_output=True, text=True)
        if done.returncode != 0:
            raise SystemExit(f"{tree}: write_results failed:\n{done.stderr[-3000:]}")
        first, second = json.loads(done.stdout.strip().splitlines()[-1])
        return tuple(first), tuple(second)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", nargs="?", type=Path, help="a run folder (default: a new demo)")
    parser.add_argument("--tree", action="append", type=Path,
                        help="a tap-bench checkout to measure (repeatable; default: this one)")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    trees = args.tree or [HERE]
    with tempfile.TemporaryDirectory(prefix="bench-report-demo-") as tmp:
        run = args.run
        if run is None:
            run = Path(tmp) / "demo"
            env = {**os.environ, "PYTHONPATH": str(trees[-1]), "OMP_WAIT_POLICY": "PASSIVE",
                   "TAP_BENCH_CACHE": str(Path(tmp) / "cache")}
            subprocess.run([sys.executable, "-m", "tap_bench", "demo", "-o", str(run),
                            "--no-progress"], env=env, check=True, stdout=subprocess.DEVNULL)
        samples: dict[Path, list] = {tree: [] for tree in trees}
        for _ in range(args.repeats):
            for tree in trees:  # alternating, so a change of load hits every tree
                samples[tree].append(measure(tree, run))
                print(f"{tree}: first {samples[tree][-1][0]}, second {samples[tree][-1][1]}",
                      flush=True)
        figures = {}
        for tree, runs in samples.items():
            figures[str(tree)] = {
                "first_call_cpu_s": round(statistics.median(r[0][0] for r in runs), 3),
                "first_call_wall_s": round(statistics.median(r[0][1] for r in runs), 3),
                "second_call_cpu_s": round(statistics.median(r[1][0] for r in runs), 3),
                "second_call_wall_s": round(statistics.median(r[1][1] for r in runs), 3),
                "load_1m_end": round(os.getloadavg()[0], 2)}
        figures["episodes"] = len(__import__("pandas").read_parquet(run / "episodes.parquet"))
    report("bench_report", figures, repeats=args.repeats)


if __name__ == "__main__":
    main()
