"""Env steps per second of `tap-bench train`, before and after issue 16, on this machine.

Each run is ``python -m tap_bench train --algo A --env highway --timesteps N --seed 0`` in a
fresh process; env steps per second = N / the training wall time the command records in
the model's ``.json`` (``train_seconds``: SB3's ``learn``, without the learning curve's
evaluations, which run between training steps and are timed apart). CPU seconds (user + sys)
are those of the command and of every process it starts: the training envs run in
``SubprocVecEnv`` workers forked by multiprocessing's forkserver, which are not this script's
children and are not waited for by the command, so this script makes itself a child
subreaper (Linux ``prctl``): orphaned descendants are re-parented to it and reaped here, and
their CPU time is counted in ``RUSAGE_CHILDREN``. Where that is not available, ``cpu_s`` says
``null`` rather than a figure without the workers.

"before" runs the code of a git commit (``--before-ref``, exported to a temporary folder)
with its defaults (from issue 16 on: a learning curve, whose evaluations are not in its
steps per second but are in its CPU seconds); "before-no-curve" the same code with
``--no-curve``, the CPU of its training alone: the summary gives each variant's CPU per step
against it (``cpu_per_step_vs_before_no_curve``), a figure the machine's load moves less
than steps per second. The other runs use this checkout with the settings given:
``n_envs`` training envs in parallel processes, on the scenario's fast variant or on the
scenario itself (``--exact``); the default (``2-envs-fast``) picks where its 2 envs run by
the cores idle at its start: with fewer than 1.5, one after the other in the command's
process ("2-envs-in-process", ``--in-process yes``); with fewer than 2.5, env 0 in the
command's process and the other in a worker ("2-envs-one", ``--in-process one``); else each
in a worker ("2-envs-workers", ``--in-process no``); the same weights in all three.
"2-envs-fast-curve" is tap-bench train's defaults, learning curve included. CPU seconds
include each process's start (imports: about 4 CPU s of a 2000-step run; an exported tree
has no compiled ``.pyc`` where ``PYTHONDONTWRITEBYTECODE`` is set, and neither does a fresh
checkout).

Usage: python benchmarks/bench_train_speed.py [--timesteps 2000] [--algos dqn,ppo]
       [--before-ref ada5ea7] [--repeats 1] [--variants before,before-no-curve,2-envs-fast]
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from machine import export, report

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = {  # name: extra arguments of `tap-bench train` ("before*": the "before" code)
    "before": [],  # its defaults: a learning curve, whose evaluations CPU seconds include
    "before-no-curve": ["--no-curve"],  # the training alone (its CPU without evaluations)
    "1-env-exact": ["--n-envs", "1", "--exact", "--no-curve"],
    "1-env-fast": ["--n-envs", "1", "--no-curve"],
    "2-envs-exact": ["--n-envs", "2", "--exact", "--no-curve"],
    "2-envs-fast": ["--n-envs", "2", "--no-curve"],  # the default of tap-bench train
    "2-envs-workers": ["--n-envs", "2", "--no-curve", "--in-process", "no"],
    "2-envs-fast-curve": [],  # all of tap-bench train's defaults: with the learning curve
    # the same 2 envs stepped one after the other in the training process (SB3's
    # DummyVecEnv) instead of in 2 worker processes: the same weights; CPU against speed
    "2-envs-in-process": ["--n-envs", "2", "--no-curve", "--in-process", "yes"],
    # env 0 in the training process, the other in a worker: the same weights
    "2-envs-one": ["--n-envs", "2", "--no-curve", "--in-process", "one"],
}


PR_SET_CHILD_SUBREAPER = 36


def become_subreaper() -> bool:
    """Make this process adopt its orphaned descendants (Linux); True when it worked."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def reap_descendants() -> None:
    """Wait for every child left (adopted workers and forkservers) until none is left."""
    while True:
        try:
            os.waitpid(-1, 0)
        except ChildProcessError:
            return


def run(source: Path, algo: str, timesteps: int, extra: list[str], out: Path,
        subreaper: bool) -> dict:
    """One training command; its env steps per second and CPU seconds (with all workers)."""
    out.mkdir(parents=True, exist_ok=True)
    model = out / f"{algo}.zip"
    env = {**os.environ, "PYTHONPATH": str(source), "PYTHONWARNINGS": "ignore"}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "tap_bench", "train", "--algo", algo,
                           "--env", "highway", "--timesteps", str(timesteps), "--seed", "0",
                           "-o", str(model), *extra], env=env, cwd=source, check=True,
                          capture_output=True, text=True)
    wall = time.perf_counter() - start
    if subreaper:
        reap_descendants()  # the forkserver and its env workers, orphaned when training ends
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    train_seconds = json.loads(model.with_suffix(".json").read_text())["params"][
        "train_seconds"]
    starting = [line for line in done.stdout.splitlines() if "training env(s)" in line]
    text = "".join(starting)
    # "in worker processes" first: a fallback's start line also says "in this process"
    where = ("one here" if "one in this process" in text else "workers"
             if "in worker processes" in text else "this process"
             if "in this process" in text else None)
    idle = re.search(r"([0-9.]+) of [0-9]+ cores idle", "".join(starting))
    return {"train_seconds": train_seconds, "steps_per_s": round(timesteps / train_seconds, 1),
            "envs_in": where, "idle_cores_at_start": float(idle.group(1)) if idle else None,
            "process_wall_s": round(wall, 1),
            "cpu_s": round(cpu, 1) if subreaper else None,
            "cpu_ms_per_step": round(1000 * cpu / timesteps, 1) if subreaper else None,
            "load_1m_after": round(os.getloadavg()[0], 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=2000)
    parser.add_argument("--algos", default="dqn,ppo")
    parser.add_argument("--before-ref", default="ada5ea7",
                        help="git commit of the code before (default: issue 16's start)")
    parser.add_argument("--variants", default=",".join(VARIANTS),
                        help="comma-separated names of " + ", ".join(VARIANTS))
    parser.add_argument("--repeats", type=int, default=1)
    args = parser.parse_args()
    subreaper = become_subreaper()
    if not subreaper:
        print("cannot adopt the env worker processes here (needs Linux prctl): cpu_s not "
              "reported", file=sys.stderr)
    figures: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        before = export(args.before_ref, out / "before") if "before" in args.variants \
            else None
        for algo in args.algos.split(","):
            for repeat in range(args.repeats):
                for name in args.variants.split(","):
                    source = before if name.startswith("before") else ROOT
                    result = run(source, algo, args.timesteps, VARIANTS[name],
                                 out / f"run{repeat}" / name, subreaper)
                    key = f"{algo} / {name}" + (f" / run {repeat}" if args.repeats > 1 else "")
                    figures[key] = result
                    print(key, result, flush=True)
        summary: dict[str, dict] = {}
        for algo in args.algos.split(","):
            for name in args.variants.split(","):
                runs = [r for k, r in figures.items() if k.split(" / ")[:2] == [algo, name]]
                cpu = [r["cpu_ms_per_step"] for r in runs]
                summary[f"{algo} / {name}"] = {
                    "median_steps_per_s": statistics.median(r["steps_per_s"] for r in runs),
                    "runs": [r["steps_per_s"] for r in runs],
                    "median_cpu_ms_per_step": None if None in cpu else statistics.median(cpu)}
            base = summary.get(f"{algo} / before")
            # CPU per step against the before code's training alone (without its curve)
            cpu_base = summary.get(f"{algo} / before-no-curve")
            for key, row in summary.items():
                if not key.startswith(f"{algo} /"):
                    continue
                if base:
                    row["speedup"] = round(row["median_steps_per_s"]
                                           / base["median_steps_per_s"], 2)
                if cpu_base and cpu_base["median_cpu_ms_per_step"] \
                        and row["median_cpu_ms_per_step"] is not None:
                    row["cpu_per_step_vs_before_no_curve"] = round(
                        row["median_cpu_ms_per_step"] / cpu_base["median_cpu_ms_per_step"], 2)
        for key, row in summary.items():
            print(key, row, flush=True)
        figures["summary (median over repeats)"] = summary
    report("train_speed", figures, timesteps=args.timesteps, seed=0, env="highway",
           before_ref=args.before_ref, cpu_includes_workers=subreaper)


if __name__ == "__main__":
    main()
