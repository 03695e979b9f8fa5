"""``tap-bench compare``: matched comparison of two policies' trajectory or label tables."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from tap_bench.sdl import LEVELS
from tap_bench.stats.bootstrap import add_bootstrap_arguments, bootstrap_from_args


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "compare", help="compare two policies: paired by seed and matched by SDL label",
        description="Compare policy A (the one evaluated, e.g. an RL agent) with the "
        "reference policy B (e.g. IDM): every difference is A minus B, and P(A better) is "
        "the probability that A beats the reference on the same seed. Each input is a "
        "trajectory table "
        "(labelled here; safety and efficiency measures computed from it) or a label table "
        "(labels only). Episodes on the same (env, seed) are paired: label agreement, "
        "per-label frequency differences and probabilities of improvement with paired "
        "score and t intervals over seeds. Episodes with the same ego label are grouped: "
        "measures compared inside each group. B's labels are also the reference for A's "
        "coverage and unique manoeuvres. Writes Parquet tables, PNG plots and report.html.")
    p.add_argument("a", help="policy A, the one evaluated: trajectory or label table "
                   "(.parquet/.csv)")
    p.add_argument("b", help="policy B, the reference A is compared with (differences are "
                   "A - B; B's labels are the coverage reference): trajectory or label table")
    p.add_argument("-o", "--output", required=True, help="results folder to write")
    p.add_argument("--names", nargs=2, metavar=("A", "B"),
                   help="policy names (default: the tables' policy column, else file names)")
    p.add_argument("--level", default="maneuver", choices=LEVELS,
                   help="SDL level compared (default maneuver)")
    p.add_argument("--thresholds", default="paper",
                   help="TAP thresholds for trajectory tables (preset or JSON; default paper)")
    p.add_argument("--metric", default="exact", choices=("exact", "levenshtein"),
                   help="label distance for the matched groups (default exact, g_SDL)")
    p.add_argument("--d-sim", type=float, default=0,
                   help="largest label distance inside a matched group (default 0)")
    add_bootstrap_arguments(p, what="bootstrap draws of the coverage and diversity intervals")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output")
    p.set_defaults(func=run)


def _name(table, given: str | None, path: str) -> str:
    if given:
        return given
    if "policy" in table.columns and table["policy"].nunique() == 1:
        return str(table["policy"].iloc[0])
    return Path(path).name.split(".")[0]


def read_policies(paths: Sequence[str], names: Sequence[str] | None, *, level: str,
                  thresholds: str) -> list[tuple[str, Any, Any, Any]]:
    """Read policies' tables (trajectory or label tables, one policy each) as ``compare``
    and ``view`` do: each named by ``names``, else its single ``policy`` value, else its file name.

    Returns:
        per input (name, episode table, label table, trajectory table or None).

    Raises:
        LabelTableError: two inputs carry one policy name.
    """
    from tap_bench.bench.episodes import episodes_from_table
    from tap_bench.errors import LabelTableError
    from tap_bench.tableio import read_table

    read = []
    for path, given in zip(paths, names or [None] * len(paths), strict=True):
        table = read_table(path)
        name = _name(table, given, path)
        if "policy" in table.columns:
            table = table.assign(policy=name)
        read.append((name, table))
    taken = [name for name, _ in read]
    if len(set(taken)) < len(taken):
        raise LabelTableError(f"the inputs {list(paths)} carry the policy names {taken}; "
                              "name them apart with --names.")
    tables = pair_recorded_scenes([table for _, table in read], taken,
                                  [str(p) for p in paths])
    return [(name, *episodes_from_table(table, level=level, thresholds=thresholds,
                                        policy=name, source=str(path)))
            for (name, _), table, path in zip(read, tables, paths, strict=True)]


def _recorded(table: Any) -> bool:
    """Whether ``table`` is a trajectory table of recorded scenes driven in closed loop
    (``tap-bench rollout --womd``: source ``womd-sim``)."""
    return ("sdl" not in table.columns and "source" in table.columns
        and bool((table["source"].astype(str) == "womd-sim").any()))


def pair_recorded_scenes(tables: Sequence[Any], names: Sequence[str], paths: Sequence[str]
                         ) -> list[Any]:
    """Trajectory tables of recorded scenes (``rollout --womd``), one policy each, made
    ready to compare and view together, paired by scenario id (SPEC section 8).

    Every policy drove the same WOMD scenarios, so each episode gets an id of its own,
    ``<WOMD id>/<policy>`` (the WOMD id kept in ``womd_scenario_id``), as a bench run names
    them. Episodes are paired by ``(env, seed)``: where the tables number the scenes alike
    (each scenario the same seed in every table: the same files in the same order) the
    seeds stay; else the seeds are numbered again by scenario id (0, 1, ... in the first
    table's order, then the scenarios only later tables hold), with a warning naming the
    files. Other tables are returned as they are.

    Raises:
        TrajectoryTableError: a table gives one scenario two seeds (two rollouts of
            different files concatenated).
    """
    import sys
    from collections import Counter

    import numpy as np

    from tap_bench.errors import TrajectoryTableError

    recorded = [i for i, table in enumerate(tables) if _recorded(table)]
    if not recorded:
        return list(tables)
    out = list(tables)
    seeds: list[dict[str, int]] = []
    for i in recorded:
        table = tables[i]
        womd = (table["womd_scenario_id"] if "womd_scenario_id" in table.columns
                else table["scenario_id"]).astype(str)
        pairs = list(dict.fromkeys(zip(womd.tolist(), table["seed"].astype(np.int64).tolist(),
                                       strict=True)))
        twice = [w for w, n in Counter(w for w, _ in pairs).items() if n > 1]
        if twice:
            raise TrajectoryTableError(
                f"{paths[i]}: scenario {twice[0]} appears under several seeds "
                f"({sorted(s for w, s in pairs if w == twice[0])}); a rollout table holds "
                "each recorded scenario once. Compare the tables of one rollout each.")
        seeds.append(dict(pairs))
        out[i] = table.assign(womd_scenario_id=womd, scenario_id=womd + "/" + names[i])
    by_seed = [sorted(mapping.items(), key=lambda item: item[1]) for mapping in seeds]
    first: dict[str, int] = {}
    for mapping in by_seed:
        for womd, seed in mapping:
            first.setdefault(womd, seed)
    alike = len(set(first.values())) == len(first) and all(
        first[w] == s for mapping in seeds for w, s in mapping.items())
    if alike:
        return out
    order = {womd: k for k, womd in enumerate(first)}
    for i in recorded:
        out[i] = out[i].assign(seed=out[i]["womd_scenario_id"].map(order).astype(np.int64))
    listed = ", ".join(paths[i] for i in recorded)
    print(f"warning: {listed} number the recorded scenes differently (rolled out on other "
          "files or in another order): the episodes are paired by scenario id, and the "
          f"seeds numbered again 0-{len(order) - 1} by scenario.", file=sys.stderr)
    return out


def _warn_if_unpaired(eps_a, eps_b, a: tuple[str, str], b: tuple[str, str]) -> None:
    """Warn (naming both files) when no (env, seed) is in both episode tables: nothing can
    be paired, and only the label-matched comparison and coverage are left."""
    import sys

    def keys(eps) -> set[tuple[str, int]]:
        return set(zip(eps["env"].astype(str), eps["seed"].astype(int), strict=True))

    if keys(eps_a) & keys(eps_b):
        return

    def seeds(eps) -> str:
        s = sorted(set(int(x) for x in eps["seed"]))
        envs = ", ".join(sorted(set(map(str, eps["env"])))) or "-"
        return f"seeds {s[0]}-{s[-1]} in {envs}" if s else "no episodes"

    print(f"warning: {a[1]} ({a[0]}: {seeds(eps_a)}) and {b[1]} ({b[0]}: {seeds(eps_b)}) "
          "share no (env, seed): no episode can be paired, so agreement and paired "
          "differences are empty. Roll both policies out on the same seeds.", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    import dataclasses
    import time

    import pandas as pd

    from tap_bench.bench.report.viewer.build import env_roads
    from tap_bench.bench.run.runner import check_output, package_versions, write_results
    from tap_bench.bench.scores.compare import matched_by_label
    from tap_bench.bench.scores.scoring import score

    check_output(args.output, args.overwrite)  # before any work
    config = bootstrap_from_args(args)
    (a, eps_a, lab_a, traj_a), (b, eps_b, lab_b, traj_b) = read_policies(
        (args.a, args.b), args.names, level=args.level, thresholds=args.thresholds)
    episodes = pd.concat([eps_a, eps_b], ignore_index=True)
    _warn_if_unpaired(eps_a, eps_b, (a, args.a), (b, args.b))
    scores = score(episodes, reference_policy=b, level=args.level, config=config,
                   comparisons=[(a, b)])
    if args.metric != "exact" or args.d_sim:
        matched = matched_by_label(episodes, a, b, metric=args.metric, d_sim=args.d_sim,
                                   config=config).assign(policy_a=a, policy_b=b)
        scores = dataclasses.replace(scores, matched=matched)
    summary = {"format": "tap-bench-compare", "run": Path(args.output).name,
               "created": time.strftime("%Y-%m-%d %H:%M:%S"),
               "suite": {"name": "compare", "description": f"{a} ({args.a}) against {b} "
                         f"({args.b})", "policies": [a, b],
                         "envs": sorted(episodes["env"].unique())},
               "level": args.level, "thresholds": args.thresholds, "reference_policy": b,
               "seeds": sorted(int(s) for s in episodes["seed"].unique()),
               "n_episodes": len(episodes),
               "n_failed": int((episodes["status"] != "ok").sum()),
               "methods": scores.methods, "versions": package_versions()}
    labels = pd.concat([lab_a, lab_b], ignore_index=True)
    # trajectory tables are kept, so the folder replays in 'tap-bench view' (label tables
    # have none to replay)
    replay = (pd.concat([traj_a, traj_b], ignore_index=True)
              if traj_a is not None and traj_b is not None else None)
    roads = env_roads(summary["suite"]["envs"]) if replay is not None else None
    folder = write_results(args.output, args.overwrite, summary, episodes, labels, replay,
                           scores, roads=roads)
    print(f"A = {a} (evaluated), B = {b} (the reference); differences are A - B")
    for row in scores.paired.itertuples():
        print(f"{row.env}: {row.n_pairs} seeds paired; same ego label on {row.agreement:.0%} "
              f"[{row.agreement_low:.0%}, {row.agreement_high:.0%}]")
    pm = scores.paired_measures
    if len(pm):
        env = "all" if (pm["env"] == "all").any() else pm["env"].iloc[0]
        for r in pm[pm["env"] == env].itertuples():
            print(f"  {r.measure:14s} {a} {r.mean_a:8.3f}  {b} {r.mean_b:8.3f}  "
                  f"diff {r.diff:+.3f} [{r.diff_low:+.3f}, {r.diff_high:+.3f}]  "
                  f"P({a} better) {r.p_improvement:.2f} [{r.p_low:.2f}, {r.p_high:.2f}]")
    print(f"wrote {folder}/ (report: {folder / 'report.html'})")
    return 0
