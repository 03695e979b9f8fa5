"""Env steps per second of PPO training on recorded scenes (``tap-bench train --env womd``),
for two versions of the code and where the two training envs run, alternating.

Each run is ``python -P -m tap_bench train --algo ppo --env womd --womd FILES --timesteps N
--seed 0 --n-envs 2 --in-process MODE --no-curve`` in a fresh process with ``PYTHONPATH`` set
to a tree (``--trees LABEL=DIR ...``: this checkout and, e.g., an export of an earlier commit).
Per run: the wall time of SB3's learn and the CPU seconds (user + sys) of the training, its
env worker included, as the model's definition records them (``train_seconds``,
``cpu_seconds``), the env steps per second of wall and per CPU second, and the load (1 min)
before and after. ``--in-process yes`` steps both envs in the learner's process (one core);
``one`` steps env 1 in a worker process (two cores busy): on a machine with two idle cores
the second is what "on 2 cores" means; on a loaded machine wall figures say little, CPU
figures more. Runs alternate (tree A, tree B, tree A, ...) so that the load moves both alike.

Usage: python benchmarks/bench_train_womd.py --womd FILES --trees before=DIR after=DIR
       [--timesteps 2048] [--modes yes one] [--repeats 2]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from machine import report


def one_run(tree: str, womd: list[str], timesteps: int, mode: str, out: Path) -> dict:
    """One training run; its figures."""
    model = out / "bench.zip"
    load = os.getloadavg()[0]
    start = time.perf_counter()
    subprocess.run([sys.executable, "-P", "-m", "tap_bench", "train", "--algo", "ppo",
                    "--env", "womd", "--womd", *womd, "--timesteps", str(timesteps),
                    "--seed", "0", "--n-envs", "2", "--in-process", mode, "--no-curve",
                    "--overwrite", "-o", str(model)],
                   env={**os.environ, "PYTHONPATH": tree, "OMP_WAIT_POLICY": "PASSIVE"},
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    params = json.loads(model.with_suffix(".json").read_text())["params"]
    train_s, cpu_s = params["train_seconds"], params.get("cpu_seconds", float("nan"))
    return {"train_wall_s": train_s, "train_cpu_s": cpu_s, "command_wall_s": round(wall, 1),
            "steps_per_s": round(timesteps / train_s, 1),
            "steps_per_cpu_s": round(timesteps / cpu_s, 1),
            "load_before": round(load, 2), "load_after": round(os.getloadavg()[0], 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--womd", nargs="+", required=True)
    parser.add_argument("--trees", nargs="+", required=True, help="LABEL=DIR ...")
    parser.add_argument("--timesteps", type=int, default=2048)
    parser.add_argument("--modes", nargs="+", default=["yes", "one"])
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    trees = dict(item.split("=", 1) for item in args.trees)
    runs = []
    with tempfile.TemporaryDirectory() as out:
        for repeat in range(args.repeats):
            for mode in args.modes:
                for label, tree in trees.items():
                    row = {"tree": label, "in_process": mode, "repeat": repeat,
                           **one_run(tree, args.womd, args.timesteps, mode, Path(out))}
                    print(json.dumps(row), flush=True)
                    runs.append(row)
    report("bench_train_womd", {"timesteps": args.timesteps, "runs": runs})


if __name__ == "__main__":
    main()
