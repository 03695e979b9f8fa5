"""``tap-bench view``: write the replay viewer of a run folder or of WOMD files and open it."""

from __future__ import annotations

import argparse
import time
import webbrowser
from pathlib import Path

from tap_bench.bench.runner import run_viewer
from tap_bench.bench.viewer import write_womd_viewer
from tap_bench.bench.viewer.build import DEFAULT_VIEW_SCENARIOS, MAX_VIEW_SCENARIOS


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "view", help="replay episodes: two policies side by side, with their labels",
        description="Write the replay viewer (one folder of HTML, JavaScript and data that "
        "opens from disk, no server) and open it in the browser. For a run folder (bench "
        "run, demo): every episode as a top-down animation with the ego's label timelines "
        "and safety measures, two policies side by side on the same seed, and a list "
        "filterable by env, policy, label, crash and novelty; it goes to RUN/viewer/. For "
        "WOMD files: every scenario with its map and the labels of every vehicle.")
    p.add_argument("paths", nargs="+", metavar="RUN_OR_FILES",
                   help="a run folder, or WOMD files (TFRecord, ScenarioNet .pkl; globs and "
                   "folders too)")
    p.add_argument("-o", "--output", help="viewer folder (default: RUN/viewer for a run, "
                   "womd-viewer/ for WOMD files)")
    p.add_argument("--thresholds", default="paper",
                   help="WOMD files: TAP thresholds, a preset or JSON file (default paper)")
    p.add_argument("--level", default="maneuver",
                   help="WOMD files: SDL level of the timelines (default maneuver)")
    p.add_argument("--max-scenarios", type=int, default=DEFAULT_VIEW_SCENARIOS,
                   help=f"WOMD files: show the first N scenarios, read one record at a time "
                   f"(default {DEFAULT_VIEW_SCENARIOS}, at most {MAX_VIEW_SCENARIOS}: each "
                   "costs about 14 MB while the viewer is built)")
    p.add_argument("--rebuild", action="store_true",
                   help="write a run's viewer again even when it exists")
    p.add_argument("--no-open", action="store_true", help="write it, do not open a browser")
    p.set_defaults(func=run)


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
    else:
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
