"""``tap-bench search``: SDL similarity search in a label table (TAP paper section 4.2).

Three kinds of reference: a trajectory of the table (``--like SCENARIO_ID:TRACK_ID``), an SDL
label (``--sdl "..."``), or a whole scenario (``--scenario ID``, ranked by the
Scenario2Vector weighted set distance).
"""

from __future__ import annotations

import argparse

import pandas as pd

from tap_bench.errors import LabelTableError
from tap_bench.sdl import AXES, LEVELS
from tap_bench.similarity.scenario_sdl import rank_scenarios, scenario_set
from tap_bench.similarity.sdl_distance import METRICS, label_set
from tap_bench.similarity.search import search, search_like
from tap_bench.tableio import check_outputs, read_table, write_table


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "search", help="find trajectories (or scenarios) with similar SDL labels",
        description="Search a label table for every trajectory whose SDL label is within "
        "--d-sim of a reference: another trajectory (--like), a label (--sdl), or rank whole "
        "scenarios by their scenario-level SDL (--scenario).")
    p.add_argument("labels", help="label table from 'tap-bench label' (.parquet or .csv)")
    ref = p.add_mutually_exclusive_group(required=True)
    ref.add_argument("--like", metavar="SCENARIO_ID:TRACK_ID[:SEGMENT]",
                     help="the reference is this trajectory's label (itself left out)")
    ref.add_argument("--sdl", metavar="LABEL",
                     help='the reference label, e.g. "Straight > Left Merge > Straight | '
                     'Maintain Medium Speed"')
    ref.add_argument("--scenario", metavar="SCENARIO_ID",
                     help="rank the other scenarios by the weighted set distance")
    p.add_argument("--metric", choices=METRICS, default="exact",
                   help="label distance: exact (g_SDL, 0 or 1) or levenshtein (token edits)")
    p.add_argument("--d-sim", type=float, default=0.0,
                   help="keep labels within this distance (<=; default 0: the exact label)")
    p.add_argument("--level", choices=LEVELS, default=None,
                   help="SDL level (needed when the table holds several)")
    p.add_argument("--axes", default=None, metavar="AXES",
                   help="comma-separated axes a label is made of: lateral, longitudinal, "
                   "interaction (default: lateral,longitudinal; interaction needs a table "
                   "labelled with --interactions). The --sdl reference then joins one "
                   "sequence per axis with ' | '")
    p.add_argument("--trajectories", help="trajectory table, for --scenario with --radius "
                   "(and road_type elements)")
    p.add_argument("--radius", type=float, help="--scenario: actors are the tracks within "
                   "this distance of the ego [m]")
    p.add_argument("--multiset", action="store_true",
                   help="--scenario: count actors and actions instead of sets")
    p.add_argument("--top", type=int, default=20, help="rows to print (default 20)")
    p.add_argument("-o", "--output", help="write every match here (.parquet or .csv)")
    p.set_defaults(func=run)


def _split_like(value: str, labels: pd.DataFrame) -> tuple[str, str, int | None]:
    """SCENARIO_ID:TRACK_ID[:SEGMENT], read so that ids holding ':' still work."""
    pairs = set(zip(labels["scenario_id"].astype(str), labels["track_id"].astype(str),
                    strict=True))
    scenario, _, track = value.rpartition(":")
    if (scenario, track) in pairs:
        return scenario, track, None
    head, _, segment = value.rpartition(":")
    scenario, _, track = head.rpartition(":")
    if (scenario, track) in pairs and segment.isdigit():
        return scenario, track, int(segment)
    scenario, _, track = value.rpartition(":")
    if not scenario:
        raise LabelTableError(f"--like {value!r}: give SCENARIO_ID:TRACK_ID (or "
                              "SCENARIO_ID:TRACK_ID:SEGMENT).")
    return scenario, track, None  # search_like names what is missing


def run(args: argparse.Namespace) -> int:
    check_outputs([args.output], [args.labels, args.trajectories])
    table = read_table(args.labels)
    if args.scenario is not None:
        return _run_scenario(args, table)
    ls = label_set(table, args.level, axes=args.axes, source=str(args.labels))
    if args.like is not None:
        scenario, track, segment = _split_like(args.like, ls.table)
        found = search_like(ls, scenario, track, segment, metric=args.metric, d_sim=args.d_sim)
        reference = found.attrs.get("reference") or _label_of(ls, scenario, track, segment)
    else:
        found = search(ls, args.sdl, metric=args.metric, d_sim=args.d_sim)
        reference = args.sdl
    axes = "" if ls.axes == AXES else f", axes {' | '.join(ls.axes)}"
    print(f"reference ({ls.level} level{axes}): {reference}")
    print(f"{len(found):,} of {len(ls):,} trajectories within {args.metric} distance "
          f"{args.d_sim:g}")
    if len(found):
        key = "label" if "label" in found.columns else "sdl"
        counts = found.groupby(["distance", key], sort=True).size()
        print(f"{len(counts):,} distinct label(s); nearest first:")
        for (dist, text), n in counts.head(args.top).items():
            print(f"  d={dist:<3g} {n:6d}  {text}")
    if args.output:
        write_table(found, args.output)
        print(f"wrote {args.output}")
    return 0


def _label_of(ls, scenario: str, track: str, segment: int | None) -> str:
    from tap_bench.similarity.search import find_reference

    return str(ls.labels[ls.code[find_reference(ls, scenario, track, segment)]])


def _run_scenario(args: argparse.Namespace, table: pd.DataFrame) -> int:
    trajectories = read_table(args.trajectories) if args.trajectories else None
    scenarios = scenario_set(table, trajectories, level=args.level or "action",
                             radius=args.radius, multiset=args.multiset,
                             source=str(args.labels))
    query = scenarios.description(args.scenario)
    ranked = rank_scenarios(args.scenario, scenarios)
    print(f"scenario {args.scenario}: {len(query.actors)} actor type(s), "
          f"{len(query.actions)} action(s), {len(query.elements)} element(s)")
    for part in ("actors", "actions", "elements"):
        names = sorted(query.part(part).items())
        if names:
            print(f"  {part}: " + ", ".join(n if c == 1 else f"{n} x{c}" for n, c in names))
    print(f"{len(ranked):,} other scenario(s), nearest first (weights 6, 3, 18, 9, 2, 1; ties: "
          "same action set first):")
    print(ranked.head(args.top).to_string(index=False))
    if args.output:
        write_table(ranked, args.output)
        print(f"wrote {args.output}")
    return 0
