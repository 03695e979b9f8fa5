"""``tap()`` on one episode (issue 24 section 1: <= 5 ms per single episode, with the ego's
interactions too): CPU per call, for one or more tap-bench checkouts.

The episode is highway with IDM/MOBIL, seed 0, 15 s (the suite's highway: 3,171 rows,
time-major as the simulator writes them), rolled out once with ``tap-bench rollout``; or
one episode of a run folder's ``trajectories.parquet`` (``--run DIR``: the first episode of
``tap-bench demo``'s run is its highway IDM seed 0, 11 vehicles, 1,661 rows, the episode
issue 24 quotes).
Each checkout runs in a fresh interpreter with it first on ``PYTHONPATH``: after 20 warm-up
calls, ``--calls`` calls of ``tap(table)`` and of ``tap(table, interactions="ego")``, each
timed as CPU (user + sys, ``time.process_time``) and wall; the figure is the median over
``--repeats`` interpreters, the checkouts alternating so that a change of load hits each.
The machine is shared: read CPU, not wall; ``cpu_best_block`` (the median over the
interpreters of the least CPU per call over one tenth of the calls) is the least disturbed
by other jobs (on a loaded 2-core machine the plain CPU per call moves by 20 % run to run).

Usage: ``python benchmarks/bench_tap_episode.py [--run DIR] [--tree DIR ...] [--calls 200]
[--repeats 3]``.
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
import json, sys, time, warnings
import pandas as pd
warnings.simplefilter("ignore")
from tap_bench.labelling import tap

table = pd.read_parquet(sys.argv[1])
calls = int(sys.argv[2])
out = {}
for name, kwargs in (("tap", {}), ("tap_interactions_ego", {"interactions": "ego"})):
    for _ in range(20):
        tap(table, **kwargs)
    blocks = []  # CPU per call of each tenth of the calls: the least disturbed one
    c0, w0 = time.process_time(), time.perf_counter()
    for block in range(10):
        b0 = time.process_time()
        for _ in range(calls // 10):
            tap(table, **kwargs)
        blocks.append((time.process_time() - b0) / (calls // 10) * 1e3)
    out[name] = ((time.process_time() - c0) / calls * 1e3,
                 (time.perf_counter() - w0) / calls * 1e3, min(blocks))
import tap_bench
print(json.dumps({"times": out, "tap_bench": tap_bench.__file__}))
"""


def measure(tree: Path, table: Path, calls: int) -> dict[str, list[float]]:
    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_WAIT_POLICY": "PASSIVE"}
    # run in the table's (temporary) folder: ``python -c`` puts the working folder first on
    # the path, and started inside a checkout every tree would time that checkout's code
    done = subprocess.run([sys.executable, "-c", CHILD, str(table), str(calls)], env=env,
                          capture_output=True, text=True, cwd=table.parent)
    if done.returncode != 0:
        raise SystemExit(f"{tree}: failed:\n{done.stderr[-3000:]}")
    result = json.loads(done.stdout.strip().splitlines()[-1])
    if not Path(result["tap_bench"]).resolve().is_relative_to(tree.resolve()):
        raise SystemExit(f"{tree}: the child imported {result['tap_bench']}, not this tree")
    return result["times"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tree", action="append", type=Path,
                        help="a tap-bench checkout to measure (repeatable; default: this one)")
    parser.add_argument("--calls", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--run", type=Path, help="a run folder: time its first episode")
    args = parser.parse_args()
    trees = args.tree or [HERE]
    with tempfile.TemporaryDirectory(prefix="bench-tap-") as tmp:
        table = Path(tmp) / "trajectories.parquet"
        import pandas as pd

        if args.run is not None:
            run = pd.read_parquet(args.run / "trajectories.parquet")
            first = run[run["scenario_id"] == run["scenario_id"].iloc[0]]
            first.reset_index(drop=True).to_parquet(table)
        else:
            env = {**os.environ, "PYTHONPATH": str(trees[-1]), "OMP_WAIT_POLICY": "PASSIVE"}
            subprocess.run([sys.executable, "-m", "tap_bench", "rollout", "--env", "highway",
                            "--policy", "idm", "--seeds", "0", "--duration", "15", "-o",
                            str(table), "--no-progress"],
                           env=env, check=True, stdout=subprocess.DEVNULL)

        rows = len(pd.read_parquet(table))
        samples: dict[Path, list] = {tree: [] for tree in trees}
        for _ in range(args.repeats):
            for tree in trees:
                samples[tree].append(measure(tree, table, args.calls))
                print(f"{tree}: {samples[tree][-1]}", flush=True)
    figures: dict = {"rows": rows, "calls": args.calls}
    for tree, runs in samples.items():
        figures[str(tree)] = {
            f"{name}_{what}_ms": round(statistics.median(r[name][k] for r in runs), 3)
            for name in runs[0] for k, what in ((0, "cpu"), (1, "wall"),
                                                (2, "cpu_best_block"))}
    figures["load_1m_end"] = round(os.getloadavg()[0], 2)
    report("bench_tap_episode", figures, repeats=args.repeats)


if __name__ == "__main__":
    main()
