"""``tap-bench coverage``: behaviour coverage and unique manoeuvres of an agent."""

from __future__ import annotations

import argparse

from tap_bench.sdl import LEVELS


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "coverage", help="how much of a reference's behaviour an agent shows, and what is new",
        description="Coverage of a reference label set by an agent's ego labels: the share of "
        "the reference's labels the agent shows, frequency-weighted, and the entropy of its "
        "labels, with intervals (see docs/benchmark.md); and its unique manoeuvres, the "
        "labels the reference never shows, as a rate with an interval and examples. The "
        "agent is a trajectory or label table with one ego per episode; the reference is a "
        "label or trajectory table (e.g. WOMD, or IDM rollouts) or, with --vocabulary, the "
        "single labels of the level.")
    p.add_argument("agent", help="the agent's trajectory or label table (.parquet/.csv)")
    ref = p.add_mutually_exclusive_group(required=True)
    ref.add_argument("--reference", help="reference corpus: label or trajectory table")
    ref.add_argument("--vocabulary", action="store_true",
                     help="use the SDL vocabulary of the level as the reference")
    p.add_argument("--level", default="maneuver", choices=LEVELS,
                   help="SDL level (default maneuver)")
    p.add_argument("--reference-tracks", default="vehicles", choices=("vehicles", "ego", "all"),
                   help="which reference trajectories count (default: every vehicle)")
    p.add_argument("--thresholds", default="paper",
                   help="TAP thresholds for trajectory tables (preset or JSON; default paper)")
    p.add_argument("--name", help="the agent's name (default: its policy column or file name)")
    p.add_argument("--examples", type=int, default=10, help="novel labels listed (10)")
    p.add_argument("--resamples", type=int, default=2000, help="bootstrap resamples (2000)")
    p.add_argument("--ci", type=float, default=0.95, help="interval level (0.95)")
    p.add_argument("--seed", type=int, default=0, help="bootstrap seed (0)")
    p.add_argument("-o", "--output", help="write the coverage and novelty rows here "
                   "(.csv/.parquet); the novel labels go beside it as <name>.novel.<suffix>")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    import pandas as pd

    from tap_bench.bench.bootstrap import BootstrapConfig
    from tap_bench.bench.coverage import corpus_reference, coverage, vocabulary_reference
    from tap_bench.bench.episodes import episodes_from_table
    from tap_bench.bench.novelty import novelty
    from tap_bench.cli.rollout import episodes_path
    from tap_bench.labelling import tap
    from tap_bench.tableio import check_outputs, read_table, write_tables

    config = BootstrapConfig(n_resamples=args.resamples, level=args.ci, seed=args.seed)
    novel_path = None
    if args.output:
        out = Path(args.output)
        novel_path = episodes_path(out).with_name(
            episodes_path(out).name.replace(".episodes.", ".novel."))
        check_outputs([out, novel_path], [args.agent, args.reference])
    table = read_table(args.agent)
    name = args.name or (str(table["policy"].iloc[0]) if "policy" in table.columns
                         and table["policy"].nunique() == 1 else Path(args.agent).stem)
    if "seed" not in table.columns:  # coverage needs episodes, not pairs: number them
        table = table.assign(seed=pd.factorize(table["scenario_id"])[0])
    episodes, _, _ = episodes_from_table(table.assign(policy=name), level=args.level,
                                         thresholds=args.thresholds, policy=name,
                                         source=str(args.agent))
    if args.vocabulary:
        reference = vocabulary_reference(args.level)
    else:
        ref_table = read_table(args.reference)
        if "sdl" not in ref_table.columns:
            ref_table = tap(ref_table, args.thresholds, source=str(args.reference)
                            ).labels(args.level)
        reference = corpus_reference(ref_table, args.level, tracks=args.reference_tracks,
                                     name=Path(args.reference).name)
    ok = episodes[(episodes["status"] == "ok") & episodes["sdl"].notna()]
    groups = [(env, sub) for env, sub in ok.groupby("env", sort=True)]
    if len(groups) > 1:
        groups.append(("all", ok))
    rows, novel_tables = [], []
    print(f"{name}: {len(ok)} episodes with an ego label at level {args.level}; reference: "
          f"{reference.description}")
    for k, (env, sub) in enumerate(groups):
        cv = coverage(sub["sdl"], reference, config=config, stream=k)
        row = {"env": env, "policy": name, **cv.row()}
        head = f"  {env or 'episodes'}: coverage {cv.coverage:.1%} [{cv.coverage_low:.1%}, " \
               f"{cv.coverage_high:.1%}], weighted {cv.weighted_coverage:.1%} " \
               f"[{cv.weighted_low:.1%}, {cv.weighted_high:.1%}], entropy " \
               f"{cv.entropy_bits:.2f} bits [{cv.entropy_low:.2f}, {cv.entropy_high:.2f}] " \
               f"({cv.n_distinct} distinct labels)"
        if reference.kind == "corpus":
            nv = novelty(sub, reference, config=config, stream=k)
            row.update(nv.row())
            novel_tables.append(nv.labels.assign(env=env, policy=name))
            head += f"; unique manoeuvres {nv.rate:.1%} [{nv.rate_low:.1%}, " \
                    f"{nv.rate_high:.1%}] of episodes, {len(nv.labels)} labels"
        rows.append(row)
        print(head)
    method = (f"{config.level:.0%} intervals; coverage and entropy: iNEXT-style augmented "
              f"bootstrap over episodes, novelty: percentile bootstrap over episodes; "
              f"{config.n_resamples} resamples, seed {config.seed}")
    print(f"  ({method})")
    if novel_tables:
        novel = novel_tables[-1]
        if len(novel):
            print(f"unique manoeuvres ({'all envs' if len(groups) > 1 else 'all'}), most "
                  "frequent first:")
            for r in novel.head(args.examples).itertuples():
                print(f"  {r.count:4d}  {r.label}   e.g. {r.example_scenario}")
    missed = cv.missed[: args.examples]  # of the last group: the pooled one
    if missed:
        print("reference labels never shown (heaviest first): " + "; ".join(missed))
    if args.output:
        outputs = {out: pd.DataFrame(rows)}
        if novel_tables:
            outputs[novel_path] = pd.concat(novel_tables, ignore_index=True)
        write_tables(outputs)  # together or not at all
        print("wrote " + " and ".join(map(str, outputs)))
    return 0
