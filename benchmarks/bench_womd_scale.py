"""`tap-bench rollout --womd` (or `tap-bench realism`, or `tap-bench bench run` on a suite of
the scenes) over many scenes: peak memory, CPU and wall time per scene, simulated steps per
CPU second (issue 37).

For each scene count N, files of the sample and development scenes repeated under new ids
are made in /tmp (``womd_repeat.py``), then the command runs in a fresh subprocess that
reports its own peak resident memory (VmHWM, the high-water mark of its own address space,
reset at exec) and CPU time (its worker processes' included); wall time, load and versions
go beside them. A child that fails stops the script with its exit code and stderr.

Usage::

    python benchmarks/bench_womd_scale.py 49 245 [--policy idm] [--traffic log]
        [--extra ARGS] [--name NAME]
    python benchmarks/bench_womd_scale.py 49 --profile   # where the time goes, in-process
    python benchmarks/bench_womd_scale.py 49 245 --command realism --traffic log \
        --extra "--no-progress --resamples 100"   # the realism score's memory
    python benchmarks/bench_womd_scale.py 49 245 --command bench-run \
        --extra "--no-progress --workers 2"   # a WOMD suite's run (log and --policy)
    python benchmarks/bench_womd_scale.py 49 --tree BEFORE --tree AFTER --repeats 3
        # two checkouts, paired: each repeat runs both, in alternating order
    python benchmarks/bench_womd_scale.py 16 --stages --tree BEFORE --tree AFTER --repeats 3
        # ... where the CPU goes per scene: imports, decoding and maps, reset, step
    python benchmarks/bench_womd_scale.py 49 --sample --tree BEFORE --tree AFTER --repeats 2
        # ... the whole command sampled (SIGPROF, 2 ms): start-up, reading, reset, step,
        # tables, writing, in ms CPU per scene

Figures go to ``benchmarks/out/<name>.json``. The last lines printed sum the runs up per
scene count and tree (simulated steps per CPU s of each run and their median, CPU s a
scene, peak memory, load), whether every run of a scene count wrote the same trajectory and
episode tables (their bytes' digest: two trees that should give the same results are
checked by the same run that times them) and, with two trees, each repeat's CPU ratio
(second / first).
"""

from __future__ import annotations

import argparse
import hashlib
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
import gc, json, os, sys, time
collections = [0.0, 0, 0.0]  # CPU s in the garbage collector, full collections, start
def collecting(phase, info):
    if phase == "start":
        collections[2] = time.thread_time()
    else:
        collections[0] += time.thread_time() - collections[2]
        collections[1] += info["generation"] == 2
gc.callbacks.append(collecting)
from tap_bench.cli import main
t0 = time.perf_counter()
report, sys.argv = sys.argv[1], ["tap-bench", *sys.argv[2:]]
code = main()  # as the tap-bench program runs it (its arguments from sys.argv)
peak = [int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM')][0]
t = os.times()
json.dump({"code": code, "peak_mb": peak / 1024, "wall_s": time.perf_counter() - t0,
           "cpu_s": t.user + t.system + t.children_user + t.children_system,
           "gc_cpu_s": collections[0], "full_collections": collections[1]},
          open(report, "w"))
sys.exit(code)
"""
"""The measuring child: ``python -c _CHILD REPORT ARGS...`` runs ``tap-bench ARGS`` as the
program does (``main()`` with the arguments in ``sys.argv``) and writes its exit code, peak
resident memory (VmHWM [MB]), wall and CPU [s] (its worker processes' included), and the
CPU [s] its main thread spent in the garbage collector and how many full collections (from
``gc.callbacks``) to REPORT; it exits with the command's code."""

COMMANDS = ("rollout", "realism", "bench-run")
"""What the script measures: ``tap-bench rollout --womd``, ``tap-bench realism`` or
``tap-bench bench run`` on a suite of the scenes (:func:`bench_suite`)."""


_STAGES = """
import collections, functools, glob, json, sys, time, warnings
warnings.simplefilter("ignore")
T = time.process_time
t0 = T()
import tap_bench.cli.rollout, tap_bench.sim.rollout_stream, tap_bench.sim.womd_env  # noqa
imports = T() - t0
from tap_bench.sim import womd_env
from tap_bench.sim.womd_scene import WomdScenes
rollout_module = sys.modules["tap_bench.sim.rollout"]
spent, calls = collections.defaultdict(float), collections.Counter()
def timed(owner, name, label):
    f = getattr(owner, name)
    if isinstance(f, type):  # a class: its constructor timed, the class left in place
        owner, name, f = f, "__init__", f.__init__
    @functools.wraps(f)
    def g(*a, **k):
        t = T()
        try:
            return f(*a, **k)
        finally:
            spent[label] += T() - t
            calls[label] += 1
    setattr(owner, name, g)
inner = womd_env._WomdHighwayEnv
for owner, name, label in ((womd_env, "load_scene", "read and decode a scene, its map"),
                           (womd_env, "WomdNetwork", "road network"),
                           (womd_env, "WomdRoad", "road (edges, signals, segments)"),
                           (inner, "_traffic_vehicle", "agents made"),
                           *([(womd_env.LogVehicle, "many", "agents made")]
                             if hasattr(womd_env.LogVehicle, "many") else []),
                           (inner, "_reset", "env _reset (network, road, agents, route)"),
                           (womd_env.WomdEnv, "reset", "env reset (all of it)"),
                           (womd_env.WomdEnv, "step", "env step"),
                           (womd_env.WomdEnv, "trajectories", "trajectory table"),
                           (rollout_module, "run_episode", "episode (reset, steps, table)")):
    timed(owner, name, label)
files = tuple(sorted(glob.glob(sys.argv[2] + "/*")))
rollout_module.rollout(WomdScenes(files[:1], traffic=sys.argv[3]), "idm", "0",
                       progress=False)  # warm: numba, with the traffic measured
spent.clear(); calls.clear()
t0 = T()
_, episodes = rollout_module.rollout(WomdScenes(files, traffic=sys.argv[3]), "idm", "all",
                                     progress=False)
total = T() - t0
n = len(episodes)
json.dump({"imports_cpu_s": round(imports, 3), "scenes": n, "rollout_cpu_s": round(total, 3),
           "ms_per_scene": {k: round(1000 * v / n, 2) for k, v in spent.items()}},
          open(sys.argv[1], "w"))
"""


_SAMPLER = """
import json, os, signal, sys
STAGES = (  # (stage, frames that mark it): the outermost stage of a sample's stack wins
    ("numba: first call, cache loads", ("numba/core/dispatcher.py:_compile_for_args",)),
    ("imports", ("<frozen importlib._bootstrap>:_find_and_load",)),
    ("catalogue", ("sim/womd_scene.py:scene_catalog",)),
    ("read: road map", ("womd/roadmap.py:scenario_road_map",
                        "womd/roadmap.py:scenarionet_road_map",
                        "womd/roadmap.py:tf_example_road_map")),
    ("read: tracks decoded", ("womd/scenario.py:decode_scenario",
                              "womd/tf_example.py:decode_tf_example",
                              "sources/scenarionet.py:decode_scenarionet",
                              "sources/scenarionet.py:load_scenarionet")),
    ("read: contract check", ("sim/womd_scene.py:checked",)),
    ("read: the rest", ("sim/womd_scene.py:load_scene",)),
    ("reset", ("sim/womd_env.py:reset",)),
    ("step", ("sim/womd_env.py:step",)),
    ("trajectory table", ("sim/womd_env.py:trajectories",)),
    ("table checked before writing", ("trajectories.py:validate_and_index",
                                      "trajectories.py:plainly_valid")),
    ("parts written", ("sim/rollout_stream.py:write",)),
    ("parts joined", ("sim/rollout_stream.py:join_parquet",)),
    ("the rest", ()),
)
counts = dict.fromkeys(name for name, _ in STAGES) | {"the rest": 0}
def key(code):
    name = code.co_filename.replace(os.sep, "/")
    for cut in ("/site-packages/", "/tap_bench/", "/lib/python"):
        if cut in name:
            name = name.split(cut, 1)[1]
            break
    return name + ":" + code.co_name
def sample(signum, frame):
    names = set()
    while frame is not None:
        names.add(key(frame.f_code))
        frame = frame.f_back
    for stage, marks in STAGES:
        if any(m in names for m in marks) or not marks:
            counts[stage] = (counts[stage] or 0) + 1
            return
signal.signal(signal.SIGPROF, sample)
signal.setitimer(signal.ITIMER_PROF, 0.002, 0.002)
from tap_bench.cli import main
report, sys.argv = sys.argv[1], ["tap-bench", *sys.argv[2:]]
code = main()  # as the tap-bench program runs it
signal.setitimer(signal.ITIMER_PROF, 0, 0)
t = os.times()
json.dump({"code": code, "cpu_s": t.user + t.system,
           "samples": {k: v or 0 for k, v in counts.items()}}, open(report, "w"))
"""


def run_sampled(folder: Path, out: Path, policy: str, traffic: str, extra: list[str],
                tree: str | None) -> dict:
    """Where the CPU of a whole ``rollout --womd`` goes, start-up included: the command in
    a fresh interpreter sampled every 2 ms of its CPU (SIGPROF), each sample given to the
    outermost stage on its stack; ms CPU per scene by stage (the samples' shares of the
    process's CPU)."""
    import pandas as pd

    report_file = out.with_suffix(".measure.json")
    files = [str(p) for p in sorted(folder.iterdir()) if not p.name.startswith(".")]
    cmd = [sys.executable, *(["-P"] if tree else []), "-c", _SAMPLER, str(report_file),
           "rollout", "--womd", *files, "--policy", policy, "--traffic", traffic, "-o",
           str(out), *extra]
    child, wall, load0 = _measured(cmd, report_file, "rollout", tree)
    scenes = len(pd.read_parquet(str(out).replace(".parquet", ".episodes.parquet")))
    total = max(sum(child["samples"].values()), 1)
    commit = subprocess.run(["git", "-C", tree, "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip() if tree else ""
    return {**({"tree": tree, "commit": commit} if tree else {}), "scenes": scenes,
            "cpu_s": round(child["cpu_s"], 2), "wall_s": round(wall, 2), "samples": total,
            "ms_per_scene": {k: round(1000 * child["cpu_s"] * v / total / scenes, 2)
                             for k, v in child["samples"].items()},
            "load_before": round(load0, 2), "load_after": round(os.getloadavg()[0], 2)}


def run_stages(folder: Path, out: Path, traffic: str, tree: str | None) -> dict:
    """Where a rollout's CPU goes per scene, in one fresh interpreter (the checkout ``tree``
    first on its path): the CLI's imports, then a rollout of the folder's scenes in-process
    after a one-scene warm-up, each stage's CPU [ms per scene] (a stage's figure includes
    the stages it calls)."""
    env = {**os.environ, "OMP_WAIT_POLICY": "PASSIVE", **({"PYTHONPATH": tree} if tree else {})}
    load0 = os.getloadavg()[0]
    proc = subprocess.run([sys.executable, *(["-P"] if tree else []), "-c", _STAGES,
                           str(out), str(folder), traffic],
                          env=env, capture_output=True, text=True)
    if proc.returncode:
        raise SystemExit(f"stages failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    row = json.loads(out.read_text())
    commit = subprocess.run(["git", "-C", tree, "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip() if tree else ""
    return {**({"tree": tree, "commit": commit} if tree else {}), **row,
            "load_before": round(load0, 2), "load_after": round(os.getloadavg()[0], 2)}


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


def scene_files(folder: Path) -> list[str]:
    """The scene files of ``folder`` (its hidden marker left out), sorted."""
    return [str(p) for p in sorted(folder.iterdir()) if not p.name.startswith(".")]


def bench_suite(files: list[str], policy: str, traffic: str) -> dict:
    """The suite ``bench-run`` measures: the scenes of ``files`` driven by the human (log,
    the reference) and by ``policy``, every scene, as ``envs/suites/womd-sample.json``."""
    policies = ["log"] if policy == "log" else ["log", policy]
    return {"name": "womd-scale", "version": 0,
            "envs": [{"womd": files, "traffic": traffic, "ego": "sdc",
                      "policy_frequency": 2}],
            "policies": policies, "reference_policy": "log", "seeds": "all",
            "level": "maneuver", "thresholds": "paper",
            "bootstrap": {"n_resamples": 200, "level": 0.95, "seed": 0}}


def child_command(command: str, files: list[str], out: Path, report_file: Path, *,
                  policy: str, traffic: str, extra: list[str], tree: str | None = None
                  ) -> list[str]:
    """The measuring child's command line (:data:`_CHILD`) for ``command`` (one of
    :data:`COMMANDS`) over ``files``, writing to ``out`` (the rollout's table, the realism
    JSON, or the run folder, whose suite is written beside it as ``<out>.suite.json``) and
    reporting to ``report_file``; ``tree``: a checkout put first on the child's path (then
    ``-P``: not the current folder)."""
    head = [sys.executable, *(["-P"] if tree else []), "-c", _CHILD, str(report_file)]
    if command == "rollout":
        return [*head, "rollout", "--womd", *files, "--policy", policy, "--traffic", traffic,
                "-o", str(out), *extra]
    if command == "realism":
        return [*head, "realism", "--womd", *files, "--policy", policy, "--traffic",
                traffic, "-o", str(out), *extra]
    if command == "bench-run":
        suite = out.with_name(out.name + ".suite.json")
        suite.write_text(json.dumps(bench_suite(files, policy, traffic), indent=1))
        # no cache: every episode simulated, labelled and scored in this run
        return [*head, "bench", "run", "--suite", str(suite), "-o", str(out), "--no-cache",
                *extra]
    raise ValueError(f"command {command!r} is not one of {', '.join(COMMANDS)}")


def _measured(cmd: list[str], report_file: Path, what: str, tree: str | None = None
              ) -> tuple[dict, float, float]:
    """Run ``cmd`` (the measuring child) with ``tree`` first on the path: (the child's
    report: peak MB and CPU s, wall [s], the load average before).

    Raises:
        SystemExit: the child failed (naming its exit code and the end of its stderr).
    """
    env = {**os.environ, "OMP_WAIT_POLICY": "PASSIVE"}
    if tree:
        env["PYTHONPATH"] = tree
    load0 = os.getloadavg()[0]
    start = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if proc.returncode or not report_file.is_file():
        raise SystemExit(f"{what} failed (exit code {proc.returncode}):\n"
                         f"{proc.stderr[-3000:]}")
    return json.loads(report_file.read_text()), wall, load0


def _commit(tree: str | None) -> dict:
    if not tree:
        return {}
    commit = subprocess.run(["git", "-C", tree, "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip()
    return {"tree": tree, "commit": commit}


def _shown(folder: Path, cmd: list[str], files: list[str]) -> str:
    """The child's command as a user types it, the scene files as one glob."""
    args = cmd[cmd.index(_CHILD) + 2:]
    if files and files[0] in args:
        at = args.index(files[0])
        args[at:at + len(files)] = [f"{folder}/*"]
    return shlex.join(["tap-bench", *args])


def run_rollout(folder: Path, out: Path, policy: str, traffic: str, extra: list[str],
                tree: str | None = None) -> dict:
    """The rollout in a fresh interpreter (with the checkout ``tree`` first on its path
    when given): its peak memory, CPU, wall and the steps."""
    import pandas as pd

    report_file = out.with_suffix(".measure.json")
    files = scene_files(folder)
    cmd = child_command("rollout", files, out, report_file, policy=policy, traffic=traffic,
                        extra=extra, tree=tree)
    child, wall, load0 = _measured(cmd, report_file, "rollout", tree)
    episodes_file = Path(str(out).replace(".parquet", ".episodes.parquet"))
    episodes = pd.read_parquet(episodes_file)
    steps = round((episodes["duration_s"].fillna(0) * 10).sum())
    scenes = len(episodes)
    return {**_commit(tree),
            "scenes": scenes, "ok": int((episodes["status"] == "ok").sum()),
            "tables_sha256": tables_digest(out, episodes_file),
            "peak_mb": round(child["peak_mb"], 1), "cpu_s": round(child["cpu_s"], 2),
            "gc_cpu_s": round(child.get("gc_cpu_s", float("nan")), 3),
            "full_collections": child.get("full_collections"),
            "wall_s": round(wall, 2), "cpu_s_per_scene": round(child["cpu_s"] / scenes, 4),
            "steps": steps, "steps_per_cpu_s": round(steps / child["cpu_s"], 1),
            "load_before": round(load0, 2), "load_after": round(os.getloadavg()[0], 2),
            "command": _shown(folder, cmd, files)}


def tables_digest(*files: Path) -> str:
    """SHA-256 of the files' bytes one after the other (the trajectory and episode tables
    of a rollout), the first 16 hex digits: two runs that wrote the same tables give the
    same digest."""
    digest = hashlib.sha256()
    for file in files:
        digest.update(Path(file).read_bytes())
    return digest.hexdigest()[:16]


def run_realism(folder: Path, out: Path, policy: str, traffic: str, extra: list[str],
                tree: str | None = None) -> dict:
    """``tap-bench realism`` in a fresh interpreter: its peak memory, CPU and wall."""
    report_file = out.with_suffix(".measure.json")
    files = scene_files(folder)
    cmd = child_command("realism", files, out, report_file, policy=policy, traffic=traffic,
                        extra=extra, tree=tree)
    child, wall, load0 = _measured(cmd, report_file, "realism", tree)
    result = json.loads(out.read_text())
    scenes = result["scenes"]
    return {**_commit(tree), "scenes": scenes, "agents": result["agents"],
            "meta_metric": result["meta_metric"], "peak_mb": round(child["peak_mb"], 1),
            "cpu_s": round(child["cpu_s"], 2), "wall_s": round(wall, 2),
            "cpu_s_per_scene": round(child["cpu_s"] / scenes, 4),
            "load_before": round(load0, 2), "load_after": round(os.getloadavg()[0], 2),
            "command": _shown(folder, cmd, files)}


def run_bench(folder: Path, out: Path, policy: str, traffic: str, extra: list[str],
              tree: str | None = None) -> dict:
    """``tap-bench bench run`` on a suite of the folder's scenes (:func:`bench_suite`) in a
    fresh interpreter: the driver's peak memory (its worker processes have their own), the
    CPU of the driver and its workers, wall, and the run's episodes."""
    import pandas as pd

    report_file = out.with_name(out.name + ".measure.json")
    files = scene_files(folder)
    cmd = child_command("bench-run", files, out, report_file, policy=policy,
                        traffic=traffic, extra=extra, tree=tree)
    child, wall, load0 = _measured(cmd, report_file, "bench run", tree)
    episodes = pd.read_parquet(out / "episodes.parquet")
    scenes = int(episodes["seed"].nunique())
    return {**_commit(tree), "scenes": scenes, "episodes": len(episodes),
            "ok": int((episodes["status"] == "ok").sum()),
            "peak_mb": round(child["peak_mb"], 1), "cpu_s": round(child["cpu_s"], 2),
            "wall_s": round(wall, 2), "cpu_s_per_scene": round(child["cpu_s"] / scenes, 4),
            "load_before": round(load0, 2), "load_after": round(os.getloadavg()[0], 2),
            "command": _shown(folder, cmd, files)}


RUNS = {"rollout": run_rollout, "realism": run_realism, "bench-run": run_bench}
"""Each command's measured run: (folder, out, policy, traffic, extra, tree) -> its row."""


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


def summary(rows: list[dict]) -> list[dict]:
    """Per scene count and tree (the runs of a whole command): the runs' simulated steps per
    CPU s, their median, CPU s a scene (median), peak memory and load (ranges); with two
    trees, each repeat's CPU ratio (second tree / first, paired in that repeat) and their
    median; per scene count, whether every rollout's output tables were the same bytes
    (``tables_sha256``)."""
    import statistics

    out = []
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        if "steps_per_cpu_s" in row:
            groups.setdefault((row["scenes"], row.get("tree")), []).append(row)
    for (scenes, tree), runs in groups.items():
        rates = [r["steps_per_cpu_s"] for r in runs]
        loads = [x for r in runs for x in (r["load_before"], r["load_after"])]
        out.append({"scenes": scenes, "tree": tree, "commit": runs[0].get("commit"),
                    "runs": len(runs), "steps_per_cpu_s": rates,
                    "median_steps_per_cpu_s": round(statistics.median(rates), 1),
                    "median_cpu_s_per_scene": round(statistics.median(
                        r["cpu_s_per_scene"] for r in runs), 4),
                    "peak_mb": [min(r["peak_mb"] for r in runs),
                                max(r["peak_mb"] for r in runs)],
                    "gc_cpu_s": [r.get("gc_cpu_s") for r in runs],
                    "load": [min(loads), max(loads)]})
    for scenes in dict.fromkeys(n for n, _ in groups):
        digests = {r["tables_sha256"] for (n, _), runs in groups.items() if n == scenes
                   for r in runs if "tables_sha256" in r}
        if digests:
            out.append({"scenes": scenes, "tables_equal": len(digests) == 1,
                        "tables_sha256": sorted(digests)})
    trees = list(dict.fromkeys(t for _, t in groups))
    if len(trees) == 2:
        for scenes in dict.fromkeys(n for n, _ in groups):
            a, b = groups.get((scenes, trees[0]), []), groups.get((scenes, trees[1]), [])
            ratios = [round(y["cpu_s"] / x["cpu_s"], 3) for x, y in zip(a, b, strict=False)]
            if ratios:
                out.append({"scenes": scenes, "pairs": f"{trees[1]} / {trees[0]} (CPU s)",
                            "ratios": ratios,
                            "median_ratio": round(statistics.median(ratios), 3)})
    return out


def print_summary(lines: list[dict]) -> None:
    """The summary's lines as text (stderr stays free for the children's)."""
    for line in lines:
        if "tables_equal" in line:
            print(f"{line['scenes']} scenes: the output tables of every run "
                  + ("are the same bytes" if line["tables_equal"] else
                     f"DIFFER ({', '.join(line['tables_sha256'])})"))
            continue
        if "ratios" in line:
            print(f"{line['scenes']} scenes, pairs {line['pairs']}: "
                  f"{', '.join(map(str, line['ratios']))} (median {line['median_ratio']})")
            continue
        print(f"{line['scenes']} scenes, {line['tree'] or 'this tree'} "
              f"({line['commit'] or '-'}): steps per CPU s "
              f"{', '.join(f'{x:,.0f}' for x in line['steps_per_cpu_s'])} (median "
              f"{line['median_steps_per_cpu_s']:,.0f}; {line['median_cpu_s_per_scene']:.4f} "
              f"CPU s a scene), peak {line['peak_mb'][0]:.1f}-{line['peak_mb'][1]:.1f} MB, "
              f"load {line['load'][0]:.2f}-{line['load'][1]:.2f}"
              + (f", garbage collection {', '.join(f'{x:.2f}' for x in gcs)} CPU s"
                 if (gcs := [x for x in line.get("gc_cpu_s", []) if x is not None]) else ""))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("counts", nargs="+", type=int)
    parser.add_argument("--policy", default="idm")
    parser.add_argument("--traffic", default="log")
    parser.add_argument("--extra", default="--no-progress",
                        help="more arguments of the command, one string (one option "
                             "alone as --extra=--OPTION)")
    parser.add_argument("--root", default=str(Path(tempfile.gettempdir()) / "tap-bench-scale"))
    parser.add_argument("--name", default="womd_scale")
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--command", choices=COMMANDS, default="rollout")
    parser.add_argument("--tree", action="append", default=[],
                        help="a tap-bench checkout to run the rollout from (repeat: before "
                             "and after, paired, in alternating order from one repeat to "
                             "the next)")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--stages", action="store_true",
                        help="where the CPU goes per scene (in-process, per tree)")
    parser.add_argument("--sample", action="store_true",
                        help="where the CPU of the whole command goes, start-up included "
                        "(sampled every 2 ms of CPU, per tree)")
    args = parser.parse_args()
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
                    if args.stages:
                        row = run_stages(folder, Path(tmp) / "stages.json", args.traffic,
                                         tree)
                    elif args.sample:
                        row = run_sampled(folder, Path(tmp) / "out.parquet", args.policy,
                                          args.traffic, shlex.split(args.extra), tree)
                    else:
                        out = Path(tmp) / {"rollout": "out.parquet", "realism": "out.json",
                                           "bench-run": "run"}[args.command]
                        row = RUNS[args.command](folder, out, args.policy, args.traffic,
                                                 shlex.split(args.extra), tree)
                print(json.dumps(row), flush=True)
                rows.append(row)
    lines = summary(rows)
    report(args.name, {"runs": rows, "summary": lines}, command=args.command,
           policy=args.policy, traffic=args.traffic, extra=args.extra)
    print_summary(lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
