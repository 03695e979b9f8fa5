"""``tap-bench envs``: the registered scenarios and their settings."""

from __future__ import annotations

import argparse
import json


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "envs", help="list the scenario envs of the suite with their settings",
        description="List the scenarios of envs/ (Gymnasium ids tap_bench/<name>-vN) with "
        "their highway-env id, episode length, decision rate, lane-change setting, default "
        "seeds and config overrides, and tap_bench/womd-v0 (recorded WOMD scenes: the files "
        "are given when it is made). Every file is validated against highway-env's defaults.")
    p.add_argument("name", nargs="?", help="show one scenario's full highway-env config")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=run)


def _seed_range(seeds: tuple[int, ...]) -> str:
    if seeds == tuple(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}-{seeds[-1]}"
    return ",".join(map(str, seeds))


WOMD_NAMES = ("womd", "womd-v0", "tap_bench/womd-v0")
"""Names ``tap-bench envs NAME`` takes for the recorded-scene env."""


def womd_row() -> dict:
    """``tap_bench/womd-v0`` as a row of the listing: its settings are the files and
    options it is made with, not a scenario file."""
    from tap_bench.sim.registration import WOMD_ENV_ID

    return {
        "id": WOMD_ENV_ID, "highway_env_id": "(WOMD lanes)",
        "duration_s": 9.1, "policy_hz": 2, "simulation_hz": 10, "lane_change": "-",
        "default_seeds": "seed % N", "overrides": {},
        "make": f"gymnasium.make('{WOMD_ENV_ID}', files=[...], traffic='log' | 'idm', "
                "ego='sdc', policy_frequency=2, config={...})",
        "description": "Recorded WOMD scenes in closed loop: the policy drives the recorded "
                       "ego from 1.0 s to the record's end (9.1 s) while the others replay "
                       "the log (traffic='log') or IDM/MOBIL drives them (traffic='idm'). "
                       "The N scenarios of the files are scenes 0 to N-1; seed s starts "
                       "scene s % N (reset options: scene, scenario_id). On the command "
                       "line: tap-bench rollout --womd FILES; in a suite: {\"womd\": "
                       "[globs], \"traffic\": ...} (docs/closed_loop.md)."}


def run(args: argparse.Namespace) -> int:
    # not tap_bench.sim.scenario_env, which imports highway-env: the files and the
    # defaults they are checked against are enough here (tap_bench.sim.schema)
    from tap_bench import catalogue
    from tap_bench.sim.scenario_format import load_scenario

    if args.name in WOMD_NAMES:
        print(json.dumps(womd_row(), indent=2))
        return 0
    if args.name:
        from tap_bench.sim.scenario_env import get_scenario

        scenarios = [get_scenario(args.name)]
    else:
        scenarios = [load_scenario(path) for path in catalogue.files("envs").values()]
    rows = [{
        "id": s.env_id, "highway_env_id": s.highway_env_id, "duration_s": s.duration,
        "policy_hz": s.policy_frequency, "simulation_hz": s.config["simulation_frequency"],
        "lane_change": s.lane_change, "default_seeds": _seed_range(s.default_seeds),
        "overrides": dict(s.overrides), "description": s.description,
    } for s in scenarios]
    if args.name:
        rows[0]["config"] = scenarios[0].env_config
    if args.json or args.name:
        print(json.dumps(rows[0] if args.name else [*rows, womd_row()], indent=2,
                         default=str))
        return 0
    header = ("id", "highway-env", "length", "decisions", "lane change", "seeds")
    table = [header] + [(r["id"], r["highway_env_id"], f"{r['duration_s']:g} s",
                         f"{r['policy_hz']} Hz", r["lane_change"], r["default_seeds"])
                        for r in [*rows, womd_row()]]
    widths = [max(len(str(row[i])) for row in table) for i in range(len(header))]
    for row in table:
        print("  ".join(str(c).ljust(w) for c, w in zip(row, widths, strict=True)).rstrip())
    print("\nAll simulate at 10 Hz and record every vehicle. Overrides:")
    for r in rows:
        print(f"  {r['id']}: {json.dumps(r['overrides'])}\n    {r['description']}")
    womd = womd_row()
    print(f"  {womd['id']}: {womd['make']}\n    {womd['description']}")
    return 0
