"""Start-up of the command line: ``tap-bench --help``, ``tap-bench envs`` and ``tap-bench
label`` on a small file (issue 16: <= 0.5 s, <= 0.5 s and <= 1 s), ``tap-bench label
--level all`` on 25,902 trajectories (``tap-bench sample --random 25880``; issue 24: <= 1 s
CPU), and what ``import tap_bench`` imports (``python -X importtime``).

Each command runs ``--repeats`` times in a fresh interpreter (``python -m tap_bench``, with
the checkout on ``PYTHONPATH``) after one warm-up run (which fills the OS file cache and
tap-bench's cache of highway-env's defaults); the figures are medians of the wall time and
of the CPU time (user + system) of the process. On a loaded machine the wall time mostly
measures waiting for a core: the CPU time is the figure that carries over to an idle one.
Give several ``--tree`` folders (checkouts of tap-bench) to compare before and after.

Each tree's bytecode is compiled first (``compileall``), as ``pip install`` leaves a package
and as a checkout's first run leaves it where Python may write it; ``--as-checked-out``
measures without that, where ``PYTHONDONTWRITEBYTECODE`` makes every process compile the
modules it imports (about 0.05 CPU s of the label command).

Usage: ``python benchmarks/bench_cli_start.py [--tree DIR ...] [--repeats 7]
[--as-checked-out]``.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from machine import report

HERE = Path(__file__).resolve().parents[1]
COMMANDS = {
    "--help": ["--help"],
    "envs": ["envs"],
    "label (18 tracks)": ["label", "small.parquet", "-o", "labels.parquet"],
    "label (25,902 tracks, all levels)": ["label", "large.parquet", "--level", "all", "-o",
                                          "labels-large.parquet"],
}


def run(tree: Path, args: list[str], cwd: Path) -> tuple[float, float]:
    """(wall, cpu) seconds of ``python -m tap_bench ARGS`` with ``tree`` first on the path."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    start = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-m", "tap_bench", *args], cwd=cwd, env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(process.pid, 0)
    wall = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{tree}: tap-bench {' '.join(args)} failed: "
                         f"{process.stderr.read().decode()[-2000:]}")
    return wall, usage.ru_utime + usage.ru_stime


def import_time(tree: Path) -> dict:
    """Cumulative import time of tap_bench and its ten most expensive imports [s]."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run([sys.executable, "-X", "importtime", "-c", "import tap_bench"],
                         env=env, capture_output=True, text=True, check=True).stderr
    rows = []
    for line in out.splitlines():
        match = re.match(r"import time:\s+(\d+) \|\s+(\d+) \|(\s*)(\S+)", line)
        if match:
            rows.append((int(match.group(2)) / 1e6, len(match.group(3)), match.group(4)))
    total = next(c for c, _, name in rows if name == "tap_bench")
    top = sorted(((c, name) for c, depth, name in rows if depth <= 5), reverse=True)[:10]
    return {"import_tap_bench_s": round(total, 3),
            "largest": {name: round(c, 3) for c, name in top}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tree", action="append", type=Path,
                        help="a tap-bench checkout to measure (repeatable; default: this one)")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--as-checked-out", action="store_true",
                        help="do not compile the trees' bytecode first: where "
                        "PYTHONDONTWRITEBYTECODE is set, every process then compiles the "
                        "modules it imports")
    args = parser.parse_args()
    trees = args.tree or [HERE]
    if not args.as_checked_out:  # as `pip install` leaves a package: its bytecode compiled
        for tree in trees:
            subprocess.run([sys.executable, "-m", "compileall", "-q", str(tree / "tap_bench")],
                           check=True)
    figures: dict = {"bytecode": "as checked out" if args.as_checked_out else
                     "compiled first (compileall), as pip installs a package"}
    with tempfile.TemporaryDirectory(prefix="bench-cli-") as tmp:
        cwd = Path(tmp)
        subprocess.run([sys.executable, "-m", "tap_bench", "sample", "-o", "sample.parquet"],
                       cwd=cwd, env={**os.environ, "PYTHONPATH": str(trees[-1])},
                       check=True, stdout=subprocess.DEVNULL)
        import pandas as pd

        sample = pd.read_parquet(cwd / "sample.parquet")
        sample[sample["scenario_id"] == "behaviours"].to_parquet(cwd / "small.parquet")
        subprocess.run([sys.executable, "-m", "tap_bench", "sample", "--random", "25880", "-o",
                        "large.parquet"], cwd=cwd, check=True, stdout=subprocess.DEVNULL,
                       env={**os.environ, "PYTHONPATH": str(trees[-1])})
        samples: dict = {(str(tree), name): [] for tree in trees for name in COMMANDS}
        for tree in trees:
            for command in COMMANDS.values():
                run(tree, command, cwd)  # warm-up
        for _ in range(args.repeats):  # the trees alternate: a change of load hits each
            for tree in trees:
                for name, command in COMMANDS.items():
                    samples[(str(tree), name)].append(run(tree, command, cwd))
        for tree in trees:
            per_tree: dict = {}
            for name in COMMANDS:
                times = samples[(str(tree), name)]
                per_tree[name] = {
                    "wall_median_s": round(statistics.median(w for w, _ in times), 3),
                    "cpu_median_s": round(statistics.median(c for _, c in times), 3),
                    "cpu_min_s": round(min(c for _, c in times), 3),
                    "wall_min_s": round(min(w for w, _ in times), 3)}
                print(f"{tree}: {name}: {per_tree[name]}", flush=True)
            per_tree["importtime"] = import_time(tree)
            figures[str(tree)] = per_tree
        figures["load_1m_end"] = round(os.getloadavg()[0], 2)
        python_only = [run_python(cwd) for _ in range(args.repeats)]
        figures["python -c pass"] = {
            "wall_median_s": round(statistics.median(w for w, _ in python_only), 3),
            "cpu_median_s": round(statistics.median(c for _, c in python_only), 3)}
    report("bench_cli_start", figures, repeats=args.repeats)


def run_python(cwd: Path) -> tuple[float, float]:
    """(wall, cpu) of a bare interpreter: the floor under every figure."""
    start = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-c", "pass"], cwd=cwd)
    _, _, usage = os.wait4(process.pid, 0)
    return time.perf_counter() - start, usage.ru_utime + usage.ru_stime


if __name__ == "__main__":
    main()
