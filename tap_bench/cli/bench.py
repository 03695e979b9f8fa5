"""``tap-bench bench``: run a benchmark suite (``bench run``), check a run against a baseline
(``bench check``), list the suites (``bench suites``) and look after the episode cache
(``bench cache``)."""

from __future__ import annotations

import argparse
import json
import os
import sys

from tap_bench.execution import add_backend_arguments
from tap_bench.progress import add_progress_arguments, progress_choice


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "bench", help="run a benchmark suite; check a run against a baseline",
        description="Benchmark suites (envs/suites/*.json): every policy in every env over "
        "the suite's seeds, labelled by TAP and scored; results/<run>/ holds Parquet tables, "
        "summary.json, PNG plots and report.html. 'bench check' is the regression gate.")
    sub = p.add_subparsers(dest="bench_command", metavar="ACTION")

    r = sub.add_parser("run", help="run a suite and write results/<run>/",
                       description="Roll out every policy of the suite in every env over its "
                       "seeds (in worker processes), label every vehicle with TAP, score "
                       "(matched comparisons, coverage, unique manoeuvres) and write the run "
                       "folder atomically. A failing episode is reported, not fatal; a run "
                       "where every episode failed is an error. Episodes already in the "
                       "episode cache are read, not simulated (the tables are the same), and "
                       "the run says how long it will take before it starts.")
    r.add_argument("--suite", default="default",
                   help="suite name (tap-bench bench suites) or JSON file (default: default)")
    r.add_argument("-o", "--output", required=True, help="run folder (results/run-001)")
    r.add_argument("--seeds", help="run these seeds instead of the suite's ('0-4', '1,4,7')")
    where = r.add_mutually_exclusive_group()
    where.add_argument("--cache", metavar="DIR", default=None,
                           help="episode cache folder: episodes whose env, policy, seed and "
                       "code did not change are read, not simulated (default: "
                       "$TAP_BENCH_CACHE, else ~/.cache/tap-bench; pruned to 2 GiB after "
                       "each run)")
    where.add_argument("--no-cache", action="store_true",
                       help="simulate every episode and leave the cache alone")
    r.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                   help="rollout processes (default 2)")
    r.add_argument("--womd", nargs="+", metavar="FILE",
                   help="WOMD files (TFRecord, ScenarioNet .pkl): a second coverage reference, "
                   "and each episode matched to its nearest WOMD scenarios (the same as "
                   "--reference WOMD=FILE,...)")
    r.add_argument("--reference", action="append", default=[], metavar="NAME=FILE[,FILE]",
                   help="another coverage and novelty reference: a label file (.parquet, "
                   ".csv with an sdl column) or driving-data files of any format 'tap-bench "
                   "ingest' reads; repeatable")
    r.add_argument("--realism", nargs="+", default=[], metavar="FILE",
                   help="results of 'tap-bench realism -o FILE' (one per traffic model) for "
                   "the report's section on the realism of simulated traffic")
    r.add_argument("--no-trajectories", action="store_true",
                   help="do not write trajectories.parquet")
    r.add_argument("--no-report", action="store_true",
                   help="write the tables and summary.json only: no plots, report.html or "
                   "replay viewer")
    r.add_argument("--log", metavar="FILE",
                   help="on recorded scenes, also append the progress lines (episodes done, "
                   "failed, skipped, rate, time left) to FILE, time-stamped")
    r.add_argument("--overwrite", action="store_true", help="replace an existing run folder")
    add_progress_arguments(r)
    add_backend_arguments(r, shards=False)
    r.set_defaults(func=run_bench)

    c = sub.add_parser("check", help="regression gate: compare a run with a baseline",
                       description="Compare a run with a baseline, per env, policy and metric "
                       "(measure means and the label distribution). A metric fails when it "
                       "moved the worse way (the measure's direction; for the label "
                       "distribution any change) by more than its margin and a one-sided "
                       "permutation test (paired by seed when the run has the baseline's "
                       "seeds; exact for rates) rejects 'no change' after the weighted Holm "
                       "correction (safety metrics first); a move the better way is "
                       "reported, never a failure; a policy or env whose definition changed "
                       "since the baseline is named with what changed. Exits 1 when "
                       "something failed, 3 when the check cannot catch a worsening of "
                       "'detect' margins with 80% power (too few seeds; "
                       "--allow-underpowered accepts that), 0 when it passed, 2 when the gate "
                       "could never fire (too few permutations or seeds). The baseline "
                       "changes only with --update-baseline.")
    c.add_argument("run", help="run folder written by 'bench run'")
    c.add_argument("--baseline", required=True, help="baseline JSON "
                   "(results/baselines/default.json)")
    c.add_argument("--update-baseline", action="store_true",
                   help="replace the baseline with this run (and exit 0)")
    c.add_argument("--all", action="store_true", help="print every check, not only moves")
    c.add_argument("-o", "--output", help="also write the check table (.csv/.parquet)")
    c.add_argument("--format", choices=("text", "json"), default="text",
                   help="json: print the verdict as one JSON object (for CI), nothing else")
    c.add_argument("--allow-underpowered", action="store_true",
                   help="exit 0 (not 3) when nothing failed but some check cannot catch "
                   "the worsening it is asked to")
    c.add_argument("--power", action="store_true",
                   help="also print, per metric, the power of the gate's rule against a "
                   "worsening of 'detect' margins at the run's seed count and the seeds "
                   "80%% power needs")
    c.set_defaults(func=check_bench)

    s = sub.add_parser("suites", help="list the benchmark suites")
    s.set_defaults(func=list_suites)

    k = sub.add_parser("cache", help="the episode cache: where it is, its size; prune it",
                       description="bench run keeps every simulated episode in a cache "
                       "(keyed by the env's resolved config, the policy's definition and "
                       "model file, the seed and the simulation code) and re-simulates only "
                       "what changed. 'info' says where it is and how big; 'prune' deletes "
                       "the least recently used episodes down to --max-size.")
    k.add_argument("action", choices=("info", "prune"), help="info or prune")
    k.add_argument("--cache", metavar="DIR", default=None,
                   help="the cache folder (default: $TAP_BENCH_CACHE, else "
                   "~/.cache/tap-bench)")
    k.add_argument("--max-size", default=None,
                   help="with prune: the size to keep, e.g. 500M, 2G, 0 to empty it "
                   "(default 2G)")
    k.set_defaults(func=cache_command)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def _references(specs: list[str]) -> dict[str, list[str]]:
    from tap_bench.errors import ParameterError

    out: dict[str, list[str]] = {}
    for spec in specs:
        name, sep, files = spec.partition("=")
        if not sep or not name or not files:
            raise ParameterError("--reference", spec, "NAME=FILE or NAME=FILE,FILE,...")
        if name in out:
            raise ParameterError("--reference", spec, "a name used once")
        out[name] = files.split(",")
    return out


def run_bench(args: argparse.Namespace) -> int:
    from tap_bench.bench.cache import EpisodeCache, default_cache_dir
    from tap_bench.bench.run.demo import timing_split
    from tap_bench.bench.run.served import serve_unchanged
    from tap_bench.execution import backend_from_args, capped_workers, close_backend

    if args.backend == "local" and not args.address:
        args.workers = capped_workers(args.workers)
    cache = None if args.no_cache else EpisodeCache(args.cache or default_cache_dir())
    references = _references(args.reference)
    plugins = getattr(args, "plugin", None) or ()

    def announce(line: str) -> None:
        print(line, flush=True)

    # an unchanged run is written from the cache before the scoring, the report and the
    # viewer are even imported
    result = serve_unchanged(args.suite, args.output, cache=cache,
                             keep_trajectories=not args.no_trajectories,
                             report=not args.no_report,
                             overwrite=args.overwrite, seeds=args.seeds,
                             corpora=bool(references or args.womd or args.realism),
                             plugins=plugins,
                             announce=announce)
    if result is None:
        from tap_bench.bench.run.runner import run_suite

        backend = (backend_from_args(args) if args.backend != "local" or args.address
            else None)
        try:
            result = run_suite(args.suite, args.output, workers=args.workers,
                               womd=args.womd, references=references,
                               keep_trajectories=not args.no_trajectories,
                               overwrite=args.overwrite, report=not args.no_report,
                               progress=progress_choice(args), backend=backend,
                               seeds=args.seeds, cache=cache, announce=announce,
                               plugins=plugins, realism=args.realism, log=args.log)
        finally:
            if backend is not None:
                close_backend(backend)
    s = result.summary
    split = timing_split(result)
    print(f"{s['n_episodes']} episodes, {s['n_failed']} failed; {split['total']:.0f} s "
          f"(rollouts {split['rollout']:.0f} s, labelling {split['labelling']:.0f} s, scoring "
          f"{split['scoring']:.1f} s, report {split['report']:.1f} s)")
    if s.get("cache"):
        print(f"episode cache {s['cache']['dir']}: {s['cache']['cached']} read, "
              f"{s['cache']['simulated']} simulated"
              + ("; the run served whole (every input unchanged)"
                 if s["cache"].get("run") == "served whole" else ""))
    for row in s["failed"][:10]:
        print(f"  failed: {row['env']} {row['policy']} seed {row['seed']}: {row['error']}",
              file=sys.stderr)
    for row in s.get("one_outcome_cells", []):
        print(f"warning: {row['env']}/{row['policy']}: all {row['n']} episodes have one "
              "outcome (the same label and measures on every seed): they are not independent "
              "samples; its intervals, pooled figures and contexts count one episode "
              f"{row['n']} times.", file=sys.stderr)
    print(f"wrote {result.folder}/ (report: "
          f"{result.report if not args.no_report else 'none, --no-report'})")
    return 0


def _no_baseline(path, summary: dict) -> None:
    """Raise the error for a missing baseline file, naming the shipped baseline of the run's
    suite where there is one (``bench check`` run outside the project's root, where the
    relative ``results/baselines/default.json`` is not)."""
    from tap_bench import catalogue
    from tap_bench.errors import FileFormatError

    suite = summary.get("suite")
    name = suite.get("name") if isinstance(suite, dict) else suite
    shipped = catalogue.find("baselines", name) if isinstance(name, str) and name else None
    hint = (f"the shipped baseline of suite '{name}' is {shipped}: give --baseline {shipped}, "
            "or " if shipped is not None and shipped.resolve() != path.resolve() else "")
    raise FileFormatError(f"{path}: no baseline file; {hint}make one from a run with "
                          f"'tap-bench bench check RUN --baseline {path} --update-baseline'.")


def check_bench(args: argparse.Namespace) -> int:
    """``bench check``: 0 passed, 1 regressed, 3 underpowered, 2 an error. An error, whatever
    it is (a damaged file, a setting that breaks the checker), is one line on stderr and
    exit 2, never 1 (the code of a regression); ``--format json`` writes ``{"status":
    "error", ...}`` on stdout."""
    try:
        return _check_bench(args)
    except Exception as err:  # every error: one line and exit 2 (Ctrl-C goes on up)
        from tap_bench.errors import TapBenchError

        message = (str(err) if isinstance(err, TapBenchError) else
            f"the check could not be made ({type(err).__name__}: {str(err)[:300]})")
        message = " ".join(message.split())
        if getattr(args, "format", "text") == "json":
            print(json.dumps({"format": "tap-bench-check", "format_version": 1,
                              "status": "error", "error": message, "run": str(args.run),
                              "baseline": str(args.baseline)}, indent=1))
        print(f"tap-bench bench check: error: {message}", file=sys.stderr)
        return 2


def _check_bench(args: argparse.Namespace) -> int:
    from pathlib import Path

    from tap_bench.bench.gate.regression import check, read_baseline, write_baseline
    from tap_bench.bench.run.runner import read_run
    from tap_bench.tableio import write_table

    summary, episodes = read_run(args.run)
    check_run_plugins(summary, args.run)
    baseline_path = Path(args.baseline)
    if args.update_baseline:
        if baseline_path.is_file():
            try:
                doc, base = read_baseline(baseline_path)
                result = check(summary, episodes, doc, base)
                print("against the old baseline: " + result.format())
            except Exception as err:  # an old or foreign baseline is being replaced anyway
                print(f"(the old baseline could not be compared: {err})")
        write_baseline(summary, episodes, baseline_path)
        print(f"baseline {baseline_path} now holds run {summary.get('run')} "
              f"({int((episodes['status'] == 'ok').sum())} episodes)")
        return 0
    if not baseline_path.exists():
        _no_baseline(baseline_path, summary)
    doc, base = read_baseline(baseline_path)
    as_json = args.format == "json"
    result = check(summary, episodes, doc, base)
    if as_json:
        verdict = result.to_json()
        verdict.update({"run": str(args.run), "baseline": str(baseline_path),
                        "allow_underpowered": bool(args.allow_underpowered)})
        print(json.dumps(verdict, indent=1))
    else:
        if not doc.get("provenance"):
            print(f"note: {baseline_path} records no policy or env definitions (made before "
                  "format 2); changed definitions cannot be named. Re-make it with "
                  "--update-baseline.")
        print(result.format(all_rows=args.all))
        if args.power:
            print_power(base.assign(status="ok"), result)
    if args.output:
        write_table(result.table, args.output)
    if result.moved:
        if not as_json:
            print(f"FAIL: the run moved the worse way against {baseline_path}; if the change "
                  "is intended, accept it with --update-baseline.")
        return 1
    if result.underpowered and not args.allow_underpowered:
        if not as_json:
            print("UNDERPOWERED: nothing failed, but this check cannot catch the worsening "
                  "it is asked to (see above); run more seeds (the baseline's), or accept "
                  "it with --allow-underpowered.")
        return 3
    if not as_json:
        print(f"OK: nothing moved the worse way beyond its margin against {baseline_path}.")
    return 0


def check_run_plugins(summary: dict, run: str) -> None:
    """A run folder is data: the plugins its ``summary.json`` names are never imported
    (only those the user names with ``--plugin``). A run whose measures are not registered
    here is refused with the fix; plugins named but not needed are said on stderr.

    Raises:
        ParameterError: a measure of the run is not registered in this process.
    """
    from tap_bench.bench.measures import MEASURES
    from tap_bench.errors import ParameterError
    from tap_bench.plugins import loaded_plugins

    named = summary.get("plugins") or []
    named = [str(p)[:200] for p in named] if isinstance(named, list) else []
    missing = [p for p in named if p not in loaded_plugins()]
    measures = summary.get("measures") or []
    unknown = ([str(m.get("name"))[:100] for m in measures if isinstance(m, dict)
               and isinstance(m.get("name"), str) and m["name"] not in MEASURES]
        if isinstance(measures, list) else [])
    if unknown:
        raise ParameterError("--plugin", " ".join(missing) or "(none)", "", message=(
            f"run {run} has measure(s) {', '.join(unknown)}, which no loaded plugin "
            f"registers. A run folder is data: its plugins ({', '.join(missing) or 'none'}) "
            "are not imported. If you trust them, name them: tap-bench bench check --plugin "
            "MODULE ..."))
    if missing:
        print(f"note: run {run} was made with plugin(s) {', '.join(missing)}, not imported "
              "(a run folder is data; --plugin MODULE imports one you trust).",
              file=sys.stderr)


def cache_command(args: argparse.Namespace) -> int:
    from tap_bench.bench.cache import EpisodeCache, default_cache_dir, parse_size

    cache = EpisodeCache(args.cache or default_cache_dir())
    if args.action == "prune":
        limit = parse_size(args.max_size) if args.max_size is not None else cache.max_bytes
        report = cache.prune(limit)
        print(f"pruned {cache.root}: removed {report.removed} entries (episodes and their labels) "
              f"({report.freed_bytes / 2**20:.1f} MiB); kept {report.kept} "
              f"({report.kept_bytes / 2**20:.1f} MiB, limit {limit / 2**20:.0f} MiB)")
        return 0
    if args.max_size is not None:
        print("tap-bench bench: error: --max-size goes with 'prune'.", file=sys.stderr)
        return 2
    entries, size = cache.size()
    print(f"episode cache {cache.root}: {entries} episode(s), {size / 2**20:.1f} MiB "
          f"(pruned to {cache.max_bytes / 2**30:.0f} GiB after each bench run)")
    return 0


def print_power(episodes, result) -> None:
    """The power of the gate's rule per metric at the check's design (paired or not, the
    run's episodes), and the seeds 80 % power needs."""
    import numpy as np
    import pandas as pd

    from tap_bench.bench.gate.power import POWER, power_summary, power_table
    from tap_bench.bench.gate.statistics import direction

    tested = result.table[result.table["p_value"].notna()]
    paired = bool(len(tested)) and (tested["test"] == "paired").all()
    n_run = int(tested["n_run"].min()) if len(tested) else None
    cells = len(tested[["env", "policy"]].drop_duplicates()) or None
    table = power_table(episodes, result.config, cells=cells, paired=paired, n_run=n_run)
    summary = power_summary(table)
    config = result.config
    print(f"power of the gate's rule against a worsening of {config.detect:g} margins "
          f"({'paired: one changed cell in play' if paired else f'unpaired: {cells} cells in play'}"
          f", alpha {config.alpha:g} weighted by metric), median and weakest (env, policy), "
          f"and the seeds the weakest needs for {POWER:.0%}:")
    print(summary.to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    if paired:  # rates: the figure above assumes nested crashes; drawn afresh is lower
        from tap_bench.bench.gate.power import afresh_rate_power
        from tap_bench.bench.gate.statistics import is_rate

        ok = episodes[episodes["status"] == "ok"]
        for metric in table["metric"].unique():
            rows = table[table["metric"] == metric]
            if not is_rate(metric) or rows.empty:
                continue
            afresh = []
            for r in rows.itertuples():
                values = pd.to_numeric(ok[(ok["env"] == r.env) & (ok["policy"] == r.policy)]
                                       [metric], errors="coerce").dropna().to_numpy(float)
                worse = values if direction(metric) < 0 else 1 - values
                afresh.append(afresh_rate_power(worse, r.effect, r.margin, r.level))
            print(f"{metric}: the power above assumes the run keeps the baseline's events "
                  f"and adds new ones (nested); if every seed's outcome is drawn afresh "
                  f"(not nested) it is {np.nanmedian(afresh):.3g} median, "
                  f"{np.nanmin(afresh):.3g} weakest.")
    for r in summary.itertuples():
        if r.cells_underpowered:
            print(f"warning: {r.metric}: {r.cells_underpowered} of {r.cells} (env, policy) "
                  f"cells catch a worsening of {r.effect:g} with less than {POWER:.0%} "
                  f"probability at {r.n} seeds; up to {r.seeds_for_power:.0f} seeds needed.")


def list_suites(args: argparse.Namespace) -> int:
    """List the catalogue's suites from their files, without importing their plugins (a
    listing runs no code a suite names; ``bench run`` imports them)."""
    from tap_bench import catalogue
    from tap_bench.bench.suite import available_suites
    from tap_bench.errors import TapBenchError
    from tap_bench.sim.scenario_format import parse_seeds, read_json

    for name in available_suites():
        try:
            doc = read_json(catalogue.find("suites", name), "suite")
            seeds = ("all" if doc.get("seeds") == "all" else
                len(parse_seeds(doc.get("seeds"), source=f"suite {name}: seeds")))
            plugins = doc.get("plugins") or []
            print(f"{name:12s} {len(doc['envs'])} envs x {len(doc['policies'])} policies x "
                  f"{seeds} seeds, level {doc.get('level', 'maneuver')}: "
                  f"{doc.get('description', '')}"
                  + (f" (plugins, imported by bench run: {', '.join(map(str, plugins))})"
                     if plugins else ""))
        except (TapBenchError, ValueError, TypeError, KeyError, OSError) as err:
            print(f"{name:12s} (cannot be read: {err})")
    return 0
