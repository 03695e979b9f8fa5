"""``tap-bench view``: write the replay viewer of a run folder or of WOMD files and open it."""

from __future__ import annotations

import argparse
import time
import webbrowser
from pathlib import Path

from tap_bench.bench.report.viewer import write_run_viewer, write_womd_viewer
from tap_bench.bench.report.viewer.build import (
    DEFAULT_VIEW_SCENARIOS,
    MAX_VIEW_SCENARIOS,
    env_roads,
)
from tap_bench.bench.run.runner import run_viewer
from tap_bench.cli.compare import read_policies
from tap_bench.errors import FileFormatError


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "view", help="replay episodes: two policies side by side, with their labels",
        description="Write the replay viewer (one folder of HTML, JavaScript and data that "
        "opens from disk, no server) and open it in the browser. For a run folder (bench "
        "run, demo): every episode as a top-down animation with the ego's label timelines "
        "and safety measures, two policies side by side on the same seed, and a list "
        "filterable by env, policy, label, crash and novelty; it goes to RUN/viewer/. For "
        "WOMD files: every scenario with its map and the labels of every vehicle. For "
        "trajectory tables (rollout output): each table a policy, side by side on one seed.")
    p.add_argument("paths", nargs="+", metavar="RUN_OR_FILES",
                   help="a run folder (bench run, demo, compare), trajectory tables "
                   "(.parquet/.csv, e.g. two rollouts side by side), or WOMD files "
                   "(TFRecord, ScenarioNet .pkl; globs and folders too, other files in "
                   "them left out)")
    p.add_argument("-o", "--output", help="viewer folder (default: RUN/viewer for a run, "
                   "tables-viewer/ for trajectory tables, womd-viewer/ for WOMD files)")
    p.add_argument("--thresholds", default="paper",
                   help="WOMD files and tables: TAP thresholds, a preset or JSON file "
                   "(default paper)")
    p.add_argument("--level", default="maneuver",
                   help="WOMD files and tables: SDL level of the timelines (default "
                   "maneuver)")
    p.add_argument("--max-scenarios", type=int, default=DEFAULT_VIEW_SCENARIOS,
                   help=f"WOMD files: show the first N scenarios, read one record at a time "
                   f"(default {DEFAULT_VIEW_SCENARIOS}, at most {MAX_VIEW_SCENARIOS}: each "
                   "costs about 14 MB while the viewer is built)")
    p.add_argument("--maps", nargs="+", metavar="WOMD_FILE",
                   help="trajectory tables of recorded scenes (rollout --womd): the WOMD "
                   "files they were rolled out on (globs and folders too), whose maps are "
                   "drawn under the episodes")
    p.add_argument("--rebuild", action="store_true",
                   help="write a run's viewer again even when it exists")
    p.add_argument("--no-open", action="store_true", help="write it, do not open a browser")
    p.set_defaults(func=run)


TABLE_SUFFIXES = (".parquet", ".csv")


def write_tables_viewer(paths: list[str], output: Path, *, level: str, thresholds: str,
                        maps: list[str] | None = None) -> Path:
    """The replay viewer of trajectory tables (``tap-bench rollout`` output): each table a
    policy (named as ``compare`` names them), their episodes side by side on one seed
    (recorded scenes: on one scenario), the last table the reference. ``maps``: the WOMD
    files recorded scenes were rolled out on, whose maps are drawn (the tables do not name
    their files). Returns the path of ``index.html``."""
    import pandas as pd

    parts = read_policies(paths, None, level=level, thresholds=thresholds)
    for path, (_, _, _, traj) in zip(paths, parts, strict=True):
        if traj is None:
            raise FileFormatError(f"{path}: a label table, no trajectories to replay; view "
                                  "the trajectory tables it was labelled from.")
    names = [part[0] for part in parts]
    episodes = pd.concat([part[1] for part in parts], ignore_index=True)
    trajectories = pd.concat([part[3] for part in parts], ignore_index=True)
    summary = {"run": output.name, "level": level, "thresholds": thresholds,
               "reference_policy": names[-1],
               "suite": {"name": "tables", "policies": names,
                         "envs": sorted(episodes["env"].astype(str).unique()),
                         "description": ", ".join(f"{n} ({p})" for n, p in
                                                  zip(names, paths, strict=True))}}
    roads = env_roads(summary["suite"]["envs"])
    if maps and "womd_scenario_id" in trajectories.columns:
        from tap_bench.sources.ingest import record_files
        from tap_bench.sources.maps import read_maps

        ids = set(trajectories["womd_scenario_id"].dropna().astype(str))
        roads = pd.concat([roads, read_maps(record_files(maps), scenario_ids=ids)],
                          ignore_index=True)
    return write_run_viewer(output, summary, episodes, trajectories, roads=roads)


def _is_run(path: Path) -> bool:
    return path.is_dir() and (path / "summary.json").is_file()


def run(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    first = Path(args.paths[0])
    if len(args.paths) == 1 and _is_run(first):
        output = Path(args.output) if args.output else first / "viewer"
        page = output / "index.html"
        if args.rebuild or not (output / "data" / "index.js").is_file():
            page = run_viewer(first, output)
            print(f"wrote {output}/ in {time.perf_counter() - start:.1f} s "
                  f"({_size(output) / 1e6:.1f} MB)")
    elif all(Path(p).suffix.lower() in TABLE_SUFFIXES and Path(p).is_file()
             for p in args.paths):
        output = Path(args.output or "tables-viewer")
        page = write_tables_viewer(args.paths, output, level=args.level,
                                   thresholds=args.thresholds, maps=args.maps)
        print(f"wrote {output}/ in {time.perf_counter() - start:.1f} s "
              f"({_size(output) / 1e6:.1f} MB)")
    else:
        tables = [p for p in args.paths if Path(p).suffix.lower() in TABLE_SUFFIXES]
        if tables and len(args.paths) > 1:
            raise FileFormatError(f"{tables[0]}: a table among other inputs; view trajectory "
                                  "tables on their own, a run folder on its own, or WOMD files.")
        output = Path(args.output or "womd-viewer")
        page = write_womd_viewer(args.paths, output, thresholds=args.thresholds,
                                 level=args.level, max_scenarios=args.max_scenarios)
        print(f"wrote {output}/ in {time.perf_counter() - start:.1f} s "
              f"({_size(output) / 1e6:.1f} MB)")
    uri = page.resolve().as_uri()
    print(f"viewer: {uri}")
    if not args.no_open:
        if not webbrowser.open(uri):
            print("(no browser found here: open the page above in one)")
    return 0


def _size(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())
