"""``tap-bench agents``: agents on real scenes over training seeds, against the human."""

from __future__ import annotations

import argparse
import os
from collections.abc import Mapping
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from tap_bench.bench.scores.agents import AgentsResult


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "agents", help="judge agents on real scenes over training seeds, against the human",
        description="Aggregate the agents of a run on recorded scenes (bench run) over "
        "training seeds x scenes as rliable recommends: route progress by its interquartile "
        "mean, at-fault collisions and off-road by their rate, each with its bootstrap "
        "interval over training seeds (whole seeds resampled; --resample task: rliable's "
        "stratified bootstrap); the probability of improvement of every agent over every "
        "other; performance profiles (a plot); the share of the human's manoeuvres each "
        "agent performs in the same scenes, the manoeuvres it adds, and its failures by its "
        "own label. A policy of kind 'seeds' (policies/ppo-womd.json) stands for its "
        "trained seeds. With --womd the suite (default womd-agents: the human, IDM, lane "
        "keeping, random and the shipped agents) is first run on those files into RUN. "
        "Writes RUN/agents/ (tables as CSV, profiles.png, agents.html; with --scenes "
        "RUN/agents/scenes-<SEEDS>/).")
    p.add_argument("run", help="run folder: read, or with --womd written first")
    p.add_argument("--womd", nargs="+", metavar="FILE",
                   help="WOMD files, folders or globs: run the suite on every scene of them "
                   "first (replacing the suite's own scenes)")
    p.add_argument("--suite", default="womd-agents",
                   help="with --womd: the suite whose policies run (default womd-agents)")
    p.add_argument("--traffic", choices=("log", "idm"), default="log",
                   help="with --womd: the other agents replay the log (default) or drive "
                   "by IDM/MOBIL")
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                   help="with --womd: rollout processes (default 2)")
    p.add_argument("--no-cache", action="store_true",
                   help="with --womd: simulate every episode (no episode cache)")
    p.add_argument("--overwrite", action="store_true",
                   help="with --womd: replace an existing run folder")
    p.add_argument("--scenes", metavar="SEEDS",
                   help="judge on these scenes only (their index in the files, as "
                   "'tap-bench train --hold-out' names them: e.g. the scenes an agent never "
                   "saw); default every scene")
    p.add_argument("--resample", choices=("run", "task"), default="run",
                   help="what the bootstrap resamples: whole training seeds (run, the "
                   "default: one model per seed drives every scene) or the seeds of each "
                   "scene on their own (task: rliable's stratified bootstrap, for one "
                   "training per scene); docs/agents.md measures both")
    p.add_argument("--level", type=float, default=0.95,
                   help="two-sided level of every interval (default 0.95)")
    p.add_argument("--resamples", type=int, default=2000,
                   help="bootstrap resamples of every interval (default 2000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the resamples (default 0)")
    p.add_argument("-o", "--output",
                   help="folder of the figures (default RUN/agents, the page of every scene "
                   "the run's report links; with --scenes RUN/agents/scenes-<SEEDS>)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from tap_bench.bench.report.agents import write_agents_page
    from tap_bench.bench.scores.agents import (
        agents_figures,
        interval_text,
        seed_groups,
        seeds_text,
    )
    from tap_bench.sim.policies import available_policies
    from tap_bench.sim.scenario_format import parse_seeds

    definitions = available_policies()
    groups = seed_groups(definitions)
    # read before the suite runs: a typo fails at once, not after the episodes
    scenes = None if args.scenes is None else list(parse_seeds(args.scenes, source="--scenes"))
    if args.womd:
        _run_suite(args)
    else:
        given = [flag for flag, value, default in (
            ("--suite", args.suite, "womd-agents"), ("--traffic", args.traffic, "log"),
            ("--workers", args.workers, min(2, os.cpu_count() or 1)),
            ("--no-cache", args.no_cache, False), ("--overwrite", args.overwrite, False))
            if value != default]
        if given:  # ignored, they would let a log-traffic run pass for an idm one
            from tap_bench.errors import ParameterError

            flags = " and ".join([", ".join(given[:-1]), given[-1]] if len(given) > 1 else given)
            raise ParameterError(given[0], True, "given with --womd", message=(
                f"{flags} {'go' if len(given) > 1 else 'goes'} with --womd (how the suite "
                f"runs): {args.run} is read as it was run. Add --womd FILES to run it, or "
                f"leave {'them' if len(given) > 1 else 'it'} out."))
    result = agents_figures(args.run, groups=groups, level=args.level,
                            n_resamples=args.resamples, seed=args.seed, scenes=scenes,
                            unit=args.resample)
    output = (Path(args.output) if args.output else Path(args.run) / "agents" if scenes is None
              # not over the page of every scene that the run's report links to
              else Path(args.run) / "agents" / f"scenes-{seeds_text(sorted(set(scenes)))}")
    viewer = os.path.relpath(Path(args.run) / "viewer" / "index.html", output)
    page = write_agents_page(result, output, viewer=viewer)
    print(_judged(result, args.run))
    for line in _trained_on(result, definitions):
        print(line)
    for row in result.aggregates.to_dict("records"):
        print(f"{row['agent']:>16}  {row['measure']:<17} {row['aggregate']:<4} "
              f"{interval_text(row)}  ({row['runs']} run(s) x {row['scenes']} scene(s))")
    means = result.coverage[result.coverage["run"] == "(mean over runs)"]
    for row in means.to_dict("records"):
        print(f"{row['agent']:>16}  covers {row['coverage']:.0%} of the human's manoeuvres")
    print(f"wrote {page} and its tables")
    if not (Path(args.run) / "viewer" / "index.html").is_file():
        print(f"the run has no replay viewer (bench run --no-report): the page's scene links "
              f"open once 'tap-bench view {args.run}' writes it")
    return 0


def _judged(result: AgentsResult, run: str) -> str:
    """The line that says what the figures are of: the scenes (their indices; those route
    progress is taken on, where the human moved, when fewer), the env and its traffic (from
    the run's ``summary.json``: ``log`` replays the other road users, ``idm`` drives them by
    IDM/MOBIL) and the intervals."""
    import json
    from pathlib import Path

    from tap_bench.bench.scores.agents import seeds_text

    traffic = {}
    try:
        suite = json.loads((Path(run) / "summary.json").read_text()).get("suite", {})
        traffic = {str(e.get("name")): str(e.get("traffic", "log"))
                   for e in suite.get("envs", []) if isinstance(e, dict) and "womd" in e}
    except (OSError, ValueError, AttributeError):
        pass  # no summary: the envs by name only
    scores = result.scores
    scenes = seeds_text(sorted({int(k) for k in scores["seed"]}))
    envs = ", ".join(f"{env}" + (f" ({traffic[env]} traffic)" if env in traffic else "")
                     for env in sorted(set(scores["env"].astype(str))))
    what = ("whole training seeds" if result.unit == "run"
            else "the seeds of each scene (stratified)")
    n = scores["task"].nunique()
    scored = result.aggregates.groupby("measure")["scenes"].max() if len(
        result.aggregates) else {}
    # a measure scored on fewer scenes: route progress, a share of the human's route, is
    # none where the human did not move
    where = "".join(f"; {str(measure).replace('_', ' ')} on the {k} where the human moved"
                    for measure, k in dict(scored).items() if k < n)
    return (f"on {n} scene(s) ({scenes}) of env {envs}{where}; intervals: "
            f"{result.level:.0%} bootstrap over {what}, {result.n_resamples} resamples")


def _trained_on(result: AgentsResult, definitions: Mapping[str, object]) -> list[str]:
    """A line per agent of the run trained on recorded scenes (its definitions record the
    files, ``train_scenes`` and ``held_out_scenes``): the scenes it trained on and those
    held out, by index in those files, and the ``--scenes`` that judges it on the latter:
    nothing else in the outputs says which scenes an agent saw in training."""
    from tap_bench.bench.scores.agents import seeds_text

    seen: dict[tuple[str, tuple], list[str]] = {}
    for agent, policy in result.scores[["agent", "policy"]].drop_duplicates().itertuples(
            index=False):
        params = dict(getattr(definitions.get(policy), "params", {}) or {})
        if not params.get("womd") or "train_scenes" not in params:
            continue
        key = (str(agent), (tuple(params["womd"]), tuple(params["train_scenes"]),
                            tuple(params.get("held_out_scenes") or ())))
        seen.setdefault(key, []).append(str(policy))
    lines = []
    for (agent, (files, train, held)), policies in seen.items():
        who = f"{agent} ({len(policies)} seed(s))" if len(policies) > 1 else agent
        line = (f"{who} trained on scenes {seeds_text(train)} of {' '.join(files)}; "
                "a scene is its index in those files, in that order")
        if held:
            line += (f": on a run of them, --scenes {seeds_text(held)} judges it on the "
                     "scenes it never saw")
        lines.append(line)
    return lines


def _run_suite(args: argparse.Namespace) -> None:
    """Run the suite's policies on the scenes of ``--womd`` (``bench run`` runs a seed group
    as its seeds)."""
    from tap_bench.bench.cache import EpisodeCache, default_cache_dir
    from tap_bench.bench.run.runner import run_suite
    from tap_bench.bench.scores.agents import HUMAN
    from tap_bench.bench.suite import load_suite, suite_from_dict
    from tap_bench.errors import ParameterError, RunExistsError

    suite = load_suite(args.suite)
    if HUMAN not in suite.policies:  # refused before its episodes run, not after
        raise ParameterError(
            "--suite", args.suite, f"a suite with the human ({HUMAN!r}, the reference) among "
            "its policies", hint=f"{args.suite!r} has {', '.join(suite.policies)}: add "
            f"{HUMAN!r} to them, or use womd-agents (the default).")
    doc = suite.to_dict()
    doc["envs"] = [{"womd": _womd_inputs(args.womd), "traffic": args.traffic}]
    doc["seeds"] = "all"
    suite = suite_from_dict(doc, source=f"{args.suite} on {' '.join(args.womd)}")
    cache = None if args.no_cache else EpisodeCache(default_cache_dir())
    try:
        run_suite(suite, args.run, workers=args.workers, overwrite=args.overwrite, cache=cache,
                  announce=lambda line: print(line, flush=True))
    except RunExistsError as err:  # the other way a user meant: judge the run as it is
        raise RunExistsError(f"{err} To judge the run it holds as it was run, leave out "
                             f"--womd: tap-bench agents {args.run}") from None


def _womd_inputs(paths: list[str]) -> list[str]:
    """``--womd`` as the suite names its scenes: files and glob patterns as given (absolute
    paths), a folder as the WOMD files in it, in the order the run reads them (the same scene
    indices; its other files left out with a note). The run's replay viewer reads the files
    again for the scenes' traffic signals and takes files and patterns, not folders (given a
    folder, it warned that the files were gone).

    Raises:
        FileFormatError: a folder without a WOMD file.
    """
    from pathlib import Path

    from tap_bench.sources.ingest import record_files

    out: list[str] = []
    for item in paths:
        if Path(item).is_dir():
            out += [os.path.abspath(f) for f in record_files([item])]
        else:
            out.append(os.path.abspath(item))
    return out
