"""`tap-bench rollout --womd` (or `tap-bench realism`) over many scenes: peak memory, CPU and
wall time per scene, simulated steps per CPU second (issue 37).

For each scene count N, files of the sample and development scenes repeated under new ids
are made in /tmp (``womd_repeat.py``), then the command runs in a fresh subprocess that
reports its own peak resident memory (VmHWM, the high-water mark of its own address space,
reset at exec) and CPU time; wall time, load and versions go beside them.

Usage::

    python benchmarks/bench_womd_scale.py 49 245 [--policy idm] [--traffic log]
        [--extra ARGS] [--name NAME]
    python benchmarks/bench_womd_scale.py 49 --profile   # where the time goes, in-process
    python benchmarks/bench_womd_scale.py 49 245 --command realism --traffic log \
        --extra "--no-progress --resamples 100"   # the realism score's memory
    python benchmarks/bench_womd_scale.py 49 --tree BEFORE --tree AFTER --repeats 3
        # two checkouts, paired: each repeat runs both, in alternating order

Figures go to ``benchmarks/out/<name>.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from machine import report
from womd_repeat import write_repeated

HERE = Path(__file__).resolve().parent

_CHILD = """
import json, os, sys, time
from tap_bench.cli import main
t0 = time.perf_counter()
code = main(sys.argv[2:])
peak = [int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM')][0]
t = os.times()
json.dump({"code": code, "peak_mb": peak / 1024, "wall_s": time.perf_counter() - t0,
           "cpu_s": t.user + t.system + t.children_user + t.children_system},
          open(sys.argv[1], "w"))
"""


def scenes_folder(n: int, root: Path) -> Path:
    """The folder of ``n`` repeated scenes under ``root`` (made once, reused)."""
    folder = root / f"womd-{n}"
    if not (folder / ".done").exists():
        import shutil
        import warnings

        shutil.rmtree(folder, ignore_errors=True)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            write_repeated(n, folder)
        (folder / ".done").write_text("")
    return folder


def run_rollout(folder: Path, out: Path, policy: str, traffic: str, extra: list[str],
                tree: str | None = None) -> dict:
    """The rollout in a fresh interpreter (with the checkout ``tree`` first on its path
    when given): its peak memory, CPU, wall and the steps."""
    import pandas as pd

    report_file = out.with_suffix(".measure.json")
    files = [str(p) for p in sorted(folder.iterdir()) if not p.name.startswith(".")]
    cmd = [sys.executable, "-c", _CHILD, str(report_file), "rollout", "--womd", *files,
           "--policy", policy, "--traffic", traffic, "-o", str(out), *extra]
    env = {**os.environ, "OMP_WAIT_POLICY": "PASSIVE"}
    if tree:
        env["PYTHONPATH"] = tree
    load0 = os.getloadavg()[0]
    start = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if proc.returncode:
        raise SystemExit(f"rollout failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    child = json.loads(report_file.read_text())
    episodes = pd.read_parquet(str(out).replace(".parquet", ".episodes.parquet"))
    steps = round((episodes["duration_s"].fillna(0) * 10).sum())
    scenes = len(episodes)
    commit = subprocess.run(["git", "-C", tree, "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip() if tree else ""
    return {**({"tree": tree, "commit": commit} if tree else {}),
            "scenes": scenes, "ok": int((episodes["status"] == "ok").sum()),
            "peak_mb": round(child["peak_mb"], 1), "cpu_s": round(child["cpu_s"], 2),
            "wall_s": round(wall, 2), "cpu_s_per_scene": round(child["cpu_s"] / scenes, 4),
            "steps": steps, "steps_per_cpu_s": round(steps / child["cpu_s"], 1),
            "load_before": round(load0, 2), "load_after": round(os.getloadavg()[0], 2),
            "command": shlex.join(["tap-bench", "rollout", "--womd", f"{folder}/*",
                                   *cmd[6 + len(files):]])}


def run_realism(folder: Path, out: Path, policy: str, traffic: str, extra: list[str]
                ) -> dict:
    """``tap-bench realism`` in a fresh interpreter: its peak memory, CPU and wall."""
    report_file = out.with_suffix(".measure.json")
    files = [str(p) for p in sorted(folder.iterdir()) if not p.name.startswith(".")]
    cmd = [sys.executable, "-c", _CHILD, str(report_file), "realism", "--womd", *files,
           "--policy", policy, "--traffic", traffic, "-o", str(out), *extra]
    env = {**os.environ, "OMP_WAIT_POLICY": "PASSIVE"}
    load0 = os.getloadavg()[0]
    start = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if proc.returncode:
        raise SystemExit(f"realism failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    child = json.loads(report_file.read_text())
    result = json.loads(out.read_text())
    scenes = result["scenes"]
    return {"scenes": scenes, "agents": result["agents"],
            "meta_metric": result["meta_metric"], "peak_mb": round(child["peak_mb"], 1),
            "cpu_s": round(child["cpu_s"], 2), "wall_s": round(wall, 2),
            "cpu_s_per_scene": round(child["cpu_s"] / scenes, 4),
            "load_before": round(load0, 2), "load_after": round(os.getloadavg()[0], 2),
            "command": shlex.join(["tap-bench", "realism", "--womd", f"{folder}/*",
                                   *cmd[6 + len(files):]])}


def profile(folder: Path, policy: str, traffic: str) -> None:
    """cProfile of the rollout in this process: the top functions by cumulative and own
    time."""
    import cProfile
    import pstats
    import warnings

    from tap_bench.sim.rollout import rollout
    from tap_bench.sim.womd_scene import WomdScenes

    files = tuple(str(p) for p in sorted(folder.iterdir()) if not p.name.startswith("."))
    prof = cProfile.Profile()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prof.enable()
        rollout(WomdScenes(files, traffic=traffic), policy, "all", progress=False)
        prof.disable()
    stats = pstats.Stats(prof).strip_dirs()
    stats.sort_stats("cumulative").print_stats(45)
    stats.sort_stats("tottime").print_stats(30)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("counts", nargs="+", type=int)
    parser.add_argument("--policy", default="idm")
    parser.add_argument("--traffic", default="log")
    parser.add_argument("--extra", default="--no-progress",
                        help="more rollout arguments, one string")
    parser.add_argument("--root", default=str(Path(tempfile.gettempdir()) / "tap-bench-scale"))
    parser.add_argument("--name", default="womd_scale")
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--command", choices=("rollout", "realism"), default="rollout")
    parser.add_argument("--tree", action="append", default=[],
                        help="a tap-bench checkout to run the rollout from (repeat: before "
                             "and after, paired, in alternating order from one repeat to "
                             "the next)")
    parser.add_argument("--repeats", type=int, default=1)
    args = parser.parse_args()
    if args.tree and args.command != "rollout":
        parser.error("--tree compares checkouts on the rollout command only")
    root = Path(args.root)
    root.mkdir(parents=True, exist_ok=True)
    if args.profile:
        profile(scenes_folder(args.counts[0], root), args.policy, args.traffic)
        return 0
    rows = []
    trees = args.tree or [None]
    for n in args.counts:
        folder = scenes_folder(n, root)
        for repeat in range(args.repeats):
            for tree in trees if repeat % 2 == 0 else trees[::-1]:
                with tempfile.TemporaryDirectory(dir=root) as tmp:
                    if args.command == "realism":
                        row = run_realism(folder, Path(tmp) / "out.json", args.policy,
                                          args.traffic, shlex.split(args.extra))
                    else:
                        row = run_rollout(folder, Path(tmp) / "out.parquet", args.policy,
                                          args.traffic, shlex.split(args.extra), tree)
                print(json.dumps(row), flush=True)
                rows.append(row)
    report(args.name, {"runs": rows}, command=args.command, policy=args.policy,
           traffic=args.traffic, extra=args.extra)
    return 0


if __name__ == "__main__":
    sys.exit(main())
