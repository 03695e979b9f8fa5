"""``tap-bench realism``: how realistic simulated traffic is on recorded scenes (SPEC 9)."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from typing import Any

import numpy as np

from tap_bench.progress import add_progress_arguments, progress_choice
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
    p.add_argument("--log", metavar="FILE",
                   help="append the progress lines (scenes done, failed, skipped, rate, "
                   "time left) to FILE as well")
    add_progress_arguments(p)
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
    from tap_bench.errors import ParameterError
    from tap_bench.progress import SceneProgress
    from tap_bench.realism.summary import SceneScores
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
    wanted = set(args.scenario or ())
    scores = SceneScores()
    skipped: list[dict[str, str]] = []
    failed: list[dict[str, str]] = []
    t0, c0 = time.perf_counter(), os.times()
    bar = SceneProgress(len(wanted) or len(env.catalog), f"realism {args.traffic}",
                        show=progress_choice(args) is not False, log=args.log)
    try:  # one scene at a time: only its values are kept (memory does not grow with scenes)
        seen = _score_scenes(env, policy, args, wanted, scores, skipped, failed, bar)
    finally:
        bar.close()
    if wanted - seen:
        raise ParameterError("--scenario", " ".join(sorted(wanted - seen)),
                             "the ids of scenarios in the files given")
    if not scores.scenes:
        reasons = "; ".join(f"{s['scene']}: {s['reason']}" for s in (skipped + failed)[:3])
        raise SceneError(f"{', '.join(args.womd)}: no scene could be scored"
                         + (f" ({reasons})" if reasons else "") + ".")
    c1 = os.times()
    result = {"traffic": args.traffic, "policy": args.policy, "rollouts": args.rollouts,
              "files": list(args.womd), **scores.summary(config), "skipped": skipped,
              "failed": failed, "cpu_seconds": c1.user + c1.system - c0.user - c0.system,
              "wall_seconds": time.perf_counter() - t0}
    result["meta_metric"] = result["overall"]["meta_metric"]["value"]
    print_table(result)
    if args.output:
        with atomic_path(args.output) as tmp:
            tmp.write_text(json.dumps(result, indent=1, default=_json_default) + "\n")
        print(f"wrote {args.output}")
    return 0


def _score_scenes(env: Any, policy: Any, args: argparse.Namespace, wanted: set[str],
                  scores: Any, skipped: list[dict[str, str]], failed: list[dict[str, str]],
                  bar: Any) -> set[str]:
    """Roll out and score every scene of ``env`` (those of ``wanted`` when given) into
    ``scores`` (:class:`~tap_bench.realism.summary.SceneScores`), one at a time: a scene
    that cannot be driven goes to ``skipped``, one whose rollout or score raised to
    ``failed`` (the run goes on), a scenario id met again is skipped (a scene is scored
    once). The scenario ids met."""
    from tap_bench.execution import describe_error
    from tap_bench.realism.rollouts import (
        SceneStates,
        agent_manoeuvres,
        scene_rollouts,
        score_scene,
    )
    from tap_bench.sim.womd_scene import SceneError

    once = args.traffic in DETERMINISTIC and args.policy == "log"
    seen: set[str] = set()
    for index in range(len(env.catalog)):
        ref = env.catalog[index]
        try:
            if wanted and env.scene_at(index).scenario_id not in wanted:
                continue
            states = scene_rollouts(env, index, policy, 1 if once else args.rollouts)
            scene = env.scene
            if scene.scenario_id in seen:
                raise SceneError(f"scenario {scene.scenario_id} was scored already from "
                                 "an earlier file: a scene is scored once")
            if once and args.rollouts > 1:
                states = SceneStates(*(np.repeat(a, args.rollouts, axis=0) for a in
                                       (states.x, states.y, states.heading, states.valid)))
            table = score_scene(scene, states, manoeuvres=agent_manoeuvres(scene))
        except SceneError as err:  # one scene that cannot be driven does not stop the run
            skipped.append({"scene": str(ref), "reason": str(err)})
            print(f"skipped {ref}: {err}")
            bar.update("skipped")
            continue
        except Exception as err:  # nor one whose rollout or score fails: named, kept
            failed.append({"scene": str(ref), "reason": describe_error(err)})
            print(f"failed {ref}: {describe_error(err)}", file=sys.stderr)
            bar.update("error")
            continue
        seen.add(scene.scenario_id)
        scores.add(table)
        del states, table
        bar.update("ok")
    return seen


def _json_default(value: Any) -> Any:
    if isinstance(value, np.integer | np.bool_):
        return value.item()
    if isinstance(value, np.floating):
        return float(value)
    raise TypeError(f"not JSON: {type(value).__name__}")
