"""``tap-bench realism``: how realistic simulated traffic is on recorded scenes (SPEC 9)."""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from typing import Any

import numpy as np

from tap_bench.sim.womd_scene import TRAFFIC
from tap_bench.stats.bootstrap import add_bootstrap_arguments, bootstrap_from_args

HELP = "score simulated traffic against the log (WOSAC 2025 realism, by manoeuvre)"
DETERMINISTIC = ("log", "constant-velocity")
"""Traffic whose rollouts are all the same with the human as the ego: run once, used K
times (the histograms still hold K copies, as K equal rollouts would give)."""


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "realism", help=HELP,
        description="Run K rollouts of every recorded scene with the chosen traffic and "
        "score the simulated agents (every agent valid at the current time but the ego) "
        "against their logged futures as the Waymo Open Sim Agents Challenge 2025 defines "
        "it: per agent and feature, a histogram of the K x T simulated values and the "
        "likelihood of the logged values under it; Bernoulli terms for collision, off-road "
        "and traffic-light violation; the meta-metric with the 2025 weights. Reported "
        "overall, per object type and per the logged agent's TAP manoeuvre, with bootstrap "
        "intervals over scenes (docs/realism.md). Baselines: --traffic constant-velocity "
        "(the floor), --traffic log (the log scored against itself, the ceiling).")
    p.add_argument("--womd", nargs="+", required=True, metavar="FILE",
                   help="recorded scenes: WOMD TFRecords, ScenarioNet pickles, patterns or "
                   "folders")
    p.add_argument("--traffic", default="idm", choices=TRAFFIC,
                   help="the traffic model scored (default idm)")
    p.add_argument("--policy", default="log",
                   help="who drives the ego (default log: the human)")
    p.add_argument("--rollouts", type=int, default=8, help="rollouts K per scene (8)")
    p.add_argument("--scenario", nargs="+", metavar="ID",
                   help="score only these scenario ids")
    add_bootstrap_arguments(p)
    p.add_argument("-o", "--output", help="write the score as JSON")
    p.set_defaults(func=run)


def _fmt(block: dict[str, Any]) -> str:
    v, lo, hi = block["value"], block["low"], block["high"]
    if not math.isfinite(v):
        return "-"
    return f"{v:.3f} [{lo:.3f}, {hi:.3f}]" if math.isfinite(lo) else f"{v:.3f}"


def print_table(result: dict[str, Any]) -> None:
    """The score as a console table: overall, then per object type and manoeuvre."""
    from tap_bench.realism.score import FEATURES

    overall = result["overall"]
    print(f"realism of {result['traffic']} traffic (ego: {result['policy']}), "
          f"{result['rollouts']} rollouts, {result['scenes']} scenes, {result['agents']} "
          f"agents: meta-metric {_fmt(overall['meta_metric'])}")
    for name in FEATURES:
        print(f"  {name:28s} {_fmt(overall[name]):26s} weight {result['weights'][name]:.2f}")
    for key, title in (("by_object_type", "object type"), ("by_manoeuvre", "manoeuvre")):
        print(f"  by {title}:")
        for group, block in result[key].items():
            print(f"    {group:16s} meta-metric {_fmt(block['meta_metric']):26s} "
                  f"{block['agents']} agents in {block['scenes']} scenes")
    print(f"  ({result['interval']}; {result['definition']})")


def run(args: argparse.Namespace) -> int:
    import pandas as pd

    from tap_bench.errors import ParameterError
    from tap_bench.realism.rollouts import (
        SceneStates,
        agent_manoeuvres,
        scene_rollouts,
        score_scene,
    )
    from tap_bench.realism.summary import summarise
    from tap_bench.sim.policies import load_policy
    from tap_bench.sim.womd_env import make_womd_env
    from tap_bench.sim.womd_scene import SceneError
    from tap_bench.tableio import atomic_path, check_outputs

    if args.rollouts < 1:
        raise ParameterError("--rollouts", args.rollouts, "a whole number >= 1")
    check_outputs([args.output], args.womd)
    config = bootstrap_from_args(args)
    env = make_womd_env(args.womd, traffic=args.traffic)
    policy = load_policy(args.policy)
    once = args.traffic in DETERMINISTIC and args.policy == "log"
    wanted = set(args.scenario or ())
    tables, skipped = [], []
    t0, c0 = time.perf_counter(), os.times()
    for index in range(len(env.catalog)):
        try:
            if wanted:
                if env.scene_at(index).scenario_id not in wanted:
                    continue
            states = scene_rollouts(env, index, policy, 1 if once else args.rollouts)
        except SceneError as err:  # one scene that cannot be driven does not stop the run
            skipped.append({"scene": str(env.catalog[index]), "reason": str(err)})
            print(f"skipped {env.catalog[index]}: {err}")
            continue
        if once and args.rollouts > 1:
            states = SceneStates(*(np.repeat(a, args.rollouts, axis=0) for a in
                                   (states.x, states.y, states.heading, states.valid)))
        scene = env.scene
        tables.append(score_scene(scene, states, manoeuvres=agent_manoeuvres(scene)))
    if wanted - {t["scenario_id"].iloc[0] for t in tables if len(t)}:
        missing = sorted(wanted - {t["scenario_id"].iloc[0] for t in tables if len(t)})
        raise ParameterError("--scenario", " ".join(missing),
                             "the ids of scenarios in the files given")
    if not tables:
        raise SceneError(f"{', '.join(args.womd)}: no scene could be scored.")
    agents = pd.concat(tables, ignore_index=True)
    c1 = os.times()
    result = {"traffic": args.traffic, "policy": args.policy, "rollouts": args.rollouts,
              "files": list(args.womd), **summarise(agents, config), "skipped": skipped,
              "cpu_seconds": c1.user + c1.system - c0.user - c0.system,
              "wall_seconds": time.perf_counter() - t0}
    result["meta_metric"] = result["overall"]["meta_metric"]["value"]
    print_table(result)
    if args.output:
        with atomic_path(args.output) as tmp:
            tmp.write_text(json.dumps(result, indent=1, default=_json_default) + "\n")
        print(f"wrote {args.output}")
    return 0


def _json_default(value: Any) -> Any:
    if isinstance(value, np.integer | np.bool_):
        return value.item()
    if isinstance(value, np.floating):
        return float(value)
    raise TypeError(f"not JSON: {type(value).__name__}")
