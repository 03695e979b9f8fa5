"""``tap-bench rollout``: run a policy on a scenario for a set of seeds."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from tap_bench.execution import add_backend_arguments, backend_from_args, close_backend
from tap_bench.progress import add_progress_arguments, progress_choice

if TYPE_CHECKING:
    import pandas as pd

    from tap_bench.sim.womd_scene import WomdScenes


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "rollout", help="run a policy on a scenario for a set of seeds",
        description="Run a policy on a scenario, one episode per seed, and write the "
        "trajectory table (every vehicle, every 0.1 s, Waymo axes) and the episode table "
        "(seed, return, length, crashed, mean speed). The same seed gives the same table, "
        "with any number of workers. A failing episode is reported and the rest kept.")
    p.add_argument("--env", help="scenario name (highway) or id")
    p.add_argument("--womd", nargs="+", metavar="FILE",
                   help="recorded WOMD scenes instead of --env: Scenario or tf.Example "
                   "TFRecords, ScenarioNet pickles, patterns or folders (files in them that "
                   "are not WOMD records are left out; tap_bench/womd-v0: the policy drives "
                   "the recorded ego from 1.0 s; a seed is a scenario's index in these "
                   "files, all of them by default; each scene is checked as ingest checks "
                   "it, and a bad one fails alone)")
    p.add_argument("--traffic", choices=("log", "idm"), default="log",
                   help="with --womd: the other agents replay the log (log, default) or "
                   "IDM/MOBIL drives the vehicles along their lanes (idm)")
    p.add_argument("--ego", default="sdc",
                   help="with --womd: the track the policy drives (default: sdc)")
    p.add_argument("--policy", required=True,
                   help="policy name (tap-bench policies), .json definition or SB3 .zip")
    p.add_argument("--seeds", help="'0-49' or '1,4,7' (default: the scenario's default seeds; "
                   "with --womd, 'all')")
    p.add_argument("-o", "--output", required=True,
                   help="trajectory table (.parquet or .csv); the episode table goes beside "
                   "it as <name>.episodes.<suffix>")
    p.add_argument("--episodes", help="episode table path (default: beside the output)")
    p.add_argument("--workers", type=int, default=1, help="processes (default 1)")
    p.add_argument("--lane-change", choices=("default", "realistic"),
                   help="override the scenario's lane-change setting")
    p.add_argument("--duration", type=float, help="override the episode length [s]")
    p.add_argument("--resume", action="store_true",
                   help="continue a run that was killed or interrupted: keep the scenes in "
                   "<output>.parts/ and run the rest (the tables equal an uninterrupted "
                   "run's)")
    p.add_argument("--ego-only", action="store_true",
                   help="write only the ego's rows of the trajectory table (on recorded "
                   "scenes a few percent of the rows: every agent of the WOMD validation "
                   "split is ~4-5 GB of Parquet); the episode table is the same")
    p.add_argument("--log", metavar="FILE",
                   help="append the progress lines (scenes done, failed, skipped, rate, "
                   "time left) to FILE as well")
    add_progress_arguments(p)
    add_backend_arguments(p, shards=False)
    p.set_defaults(func=run)


def _training_split(policy: str, scenes: WomdScenes, ok: pd.DataFrame) -> list[str]:
    """For an agent trained on recorded scenes (its definition records the split:
    ``tap-bench train --hold-out``), the summary on the scenes driven that it never saw and
    on those it trained on, apart: the two pooled would pass training scenes off as a
    test. Nothing for other policies."""
    from tap_bench.bench.scores.agents import seeds_text
    from tap_bench.errors import TapBenchError
    from tap_bench.rl.heldout import seen_in_training
    from tap_bench.sim.policies import get_definition

    try:  # a line beside the outputs, written already: it never fails the command
        definition = get_definition(policy)
        roots = [Path.cwd(), *([definition.path.parent.parent] if definition.path else [])]
        seen = seen_in_training(dict(definition.params or {}),
                                [str(r) for r in scenes.catalog()], roots)
    except (TapBenchError, OSError, ValueError) as err:
        return [f"(which scenes {policy} trained on is not known: {err})"]
    if not seen:
        return []
    lines = []
    for flag, what in ((False, "held out of its training (never seen)"),
                       (True, "trained on"), (None, "new to it (not in its training files)")):
        rows = ok[[seen[int(k)] is flag for k in ok["seed"]]]
        if len(rows):
            lines.append(
                f"  {what}: {len(rows)} scene(s) ({seeds_text(sorted(set(rows['seed'])))}): "
                f"route progress {rows['route_progress'].mean():.2f}, at-fault crash rate "
                f"{rows['crash_at_fault'].astype(bool).mean():.1%}, off road "
                f"{rows['off_road'].mean():.1%}")
    return [f"{definition.name} (its definition's training split):", *lines]


def run(args: argparse.Namespace) -> int:
    import sys

    from tap_bench.sim.rollout_stream import stream_rollout
    from tap_bench.sim.scenario_env import get_scenario
    from tap_bench.tableio import episodes_path

    output = Path(args.output)
    episodes_out = Path(args.episodes) if args.episodes else episodes_path(output)
    if bool(args.env) == bool(args.womd):
        raise SystemExit("tap-bench rollout: give either --env SCENARIO or --womd FILES.")
    if args.womd:
        from tap_bench.sim.womd_scene import WomdScenes

        env = WomdScenes(tuple(args.womd), traffic=args.traffic, ego=args.ego)
        seeds = args.seeds or "all"
    else:
        env = args.env
        seeds = args.seeds if args.seeds else list(get_scenario(args.env).default_seeds)
    workers = args.workers if args.backend == "local" or args.workers != 1 else None
    backend = backend_from_args(args, workers=workers)  # ray default: all the CPUs
    try:  # each scene's rows go to disk as it ends: memory does not grow with the scenes
        result = stream_rollout(
            env, args.policy, seeds, output, episodes_output=episodes_out, backend=backend,
            lane_change=args.lane_change, duration=args.duration, retries=args.retries,
            progress=progress_choice(args), resume=args.resume, log=args.log,
            ego_only=args.ego_only)
    finally:
        close_backend(backend)
    episodes = result.episodes
    if result.before:
        unit = "scenes" if args.womd else "episodes"
        print(f"resumed: {result.before} of {len(episodes)} {unit} were done before")
    ok = episodes[episodes["status"] == "ok"]
    print(f"{len(ok)}/{len(episodes)} episodes, {result.rows} rows -> "
          f"{output if result.output else '(no trajectories)'}; episodes -> {episodes_out}")
    if len(ok):
        crashes = f"crash rate {ok['crashed'].mean():.1%}"
        if "crash_at_fault" in ok.columns:  # real scenes: the ego's fault first (SPEC 8)
            crashes = (f"at-fault crash rate {ok['crash_at_fault'].astype(bool).mean():.1%} "
                       f"(all crashes {ok['crashed'].mean():.1%})")
        print(f"mean return {ok['return'].mean():.3f}, {crashes}, "
              f"mean ego speed {ok['mean_speed'].mean():.2f} m/s")
    if len(ok) and "off_road" in ok.columns:
        import pandas as pd

        red = pd.to_numeric(ok["ran_red_light"], errors="coerce")
        no_signals = int(red.isna().sum())
        red_text = f"{red.mean():.1%}" if red.notna().any() else "n/a"
        if no_signals:  # a number only where there is data
            red_text += f" (no signal states in {no_signals} of {len(ok)} scenes)"
        print(f"off road {ok['off_road'].mean():.1%}, route progress "
              f"{ok['route_progress'].mean():.2f}, red lights run {red_text}, log ADE "
              f"{ok['log_ade'].mean():.2f} m (full episodes: "
              f"{int(ok['log_ade'].notna().sum())} of {len(ok)})")
        if (ok["traffic"] == "idm").any():  # how clean the reactive traffic was
            print(f"idm traffic collisions (the ego's aside): "
                  f"{int(ok['traffic_collisions'].sum())} in "
                  f"{int((ok['traffic_collisions'] > 0).sum())} of {len(ok)} episodes, "
                  f"{int(ok['traffic_collisions_with_log'].sum())} with a replayed agent")
    if args.womd and len(ok):
        for line in _training_split(args.policy, env, ok):
            print(line)
    skipped = episodes[episodes["status"] == "skipped"]
    if len(skipped):
        print(f"{len(skipped)} episode(s) skipped (not failures): no route to follow")
    failed = episodes[~episodes["status"].isin(("ok", "skipped"))]
    for row in failed.itertuples():
        print(f"seed {row.seed} failed: {row.error}", file=sys.stderr)
    return 0  # every episode failed is an EpisodesFailedError, raised by rollout
