"""``tap-bench coverage``: behaviour coverage and unique manoeuvres of an agent."""

from __future__ import annotations

import argparse

from tap_bench.bench.bootstrap import add_bootstrap_arguments, bootstrap_from_args
from tap_bench.sdl import LEVELS


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "coverage", help="how much of a reference's behaviour an agent shows, and what is new",
        description="Coverage of a reference label set by an agent's ego labels: the share of "
        "the reference's labels the agent shows, frequency-weighted, and the diversity of its "
        "labels (Hill numbers with sample completeness), with intervals (see "
        "docs/benchmark.md); and its unique manoeuvres, the "
        "labels the reference never shows, as a rate with an interval and examples. The "
        "agent is a trajectory or label table with one ego per episode; the reference is a "
        "label or trajectory table (e.g. WOMD, or IDM rollouts) or, with --vocabulary, the "
        "single labels of the level. A reference with an env column (rollouts) is held "
        "against the agent's episodes of the same env only; the scores and random streams "
        "are those of 'bench run'.")
    p.add_argument("agent", help="the agent's trajectory or label table (.parquet/.csv)")
    ref = p.add_mutually_exclusive_group(required=True)
    ref.add_argument("--reference", help="reference corpus: label or trajectory table")
    ref.add_argument("--vocabulary", action="store_true",
                     help="use the SDL vocabulary of the level as the reference")
    p.add_argument("--level", default="maneuver", choices=LEVELS,
                   help="SDL level (default maneuver)")
    p.add_argument("--axes", default=None, metavar="AXES",
                   help="comma-separated axes a label is made of: lateral, longitudinal, "
                   "interaction (default lateral,longitudinal; with interaction, trajectory "
                   "tables are labelled with their egos' interactions, and label tables "
                   "must carry them)")
    p.add_argument("--reference-tracks", default="vehicles", choices=("vehicles", "ego", "all"),
                   help="which reference trajectories count (default: every vehicle)")
    p.add_argument("--thresholds", default="paper",
                   help="TAP thresholds for trajectory tables (preset or JSON; default paper)")
    p.add_argument("--name", help="the agent's name (default: its policy column or file name)")
    p.add_argument("--examples", type=int, default=10, help="novel labels listed (10)")
    add_bootstrap_arguments(p)
    p.add_argument("-o", "--output", help="write the coverage and novelty rows here "
                   "(.csv/.parquet); the novel labels go beside it as <name>.novel.<suffix>")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    import pandas as pd

    from tap_bench.bench.coverage import corpus_reference, vocabulary_reference
    from tap_bench.bench.episodes import episodes_from_table
    from tap_bench.bench.scoring import diversity_table, reference_scores
    from tap_bench.cli.rollout import episodes_path
    from tap_bench.labelling import tap
    from tap_bench.labels import label_text
    from tap_bench.sdl import check_axes
    from tap_bench.tableio import check_outputs, read_table, write_tables

    config = bootstrap_from_args(args)
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
    axes = check_axes(args.axes)
    inter = "auto" if "interaction" in axes else None
    episodes, _, _ = episodes_from_table(table.assign(policy=name), level=args.level,
                                         thresholds=args.thresholds, policy=name,
                                         source=str(args.agent), interactions=inter)
    episodes = episodes.assign(sdl=label_text(episodes, axes))  # the label on the axes
    agent_envs = sorted(set(episodes["env"]))
    if args.vocabulary:
        reference = vocabulary_reference(args.level, axes=axes)
        ref_name = f"{args.level} vocabulary"
    else:
        ref_table = read_table(args.reference)
        if "sdl" not in ref_table.columns:
            ref_table = tap(ref_table, args.thresholds, source=str(args.reference),
                            interactions="all" if inter else None).labels(args.level)
        ref_name = Path(args.reference).name
        if "env" in ref_table.columns and set(agent_envs) <= set(ref_table["env"].unique()) \
                and agent_envs != [""]:  # rollouts: a label is (env, label)
            reference = {env: corpus_reference(ref_table[ref_table["env"] == env],
                                               args.level, tracks=args.reference_tracks,
                                               name=f"{ref_name} ({env})", axes=axes)
                         for env in agent_envs}
        else:
            reference = corpus_reference(ref_table, args.level, tracks=args.reference_tracks,
                                         axes=axes,
                                         name=ref_name)
    cov, nov, novel = reference_scores(episodes, reference, ref_name, config=config)
    div = diversity_table(episodes, config)
    ok = episodes[(episodes["status"] == "ok") & episodes["sdl"].notna()]
    described = reference.description if not isinstance(reference, dict) else \
        "; ".join(r.description for r in reference.values())
    print(f"{name}: {len(ok)} episodes with an ego label at level {args.level}; reference: "
          f"{described}")
    rows = []
    for r in cov.itertuples(index=False):
        d = div[div["env"] == r.env].iloc[0] if (div["env"] == r.env).any() else None
        head = (f"  {r.env or 'episodes'}: coverage {r.coverage:.1%} [{r.coverage_low:.1%}, "
                f"{r.coverage_high:.1%}], weighted {r.weighted_coverage:.1%} "
                f"[{r.weighted_low:.1%}, {r.weighted_high:.1%}]")
        row = r._asdict()
        if d is not None:
            head += f"; {diversity_text(d)}"
            row.update({k: d[k] for k in div.columns if k not in ("env", "policy", "n")})
        match = nov[nov["env"] == r.env] if len(nov) else nov
        if len(match):
            v = match.iloc[0]
            head += (f"; unique manoeuvres {v['novel_rate']:.1%} [{v['novel_low']:.1%}, "
                     f"{v['novel_high']:.1%}] of episodes, {int(v['n_novel_labels'])} labels")
            row.update({k: v[k] for k in nov.columns if k not in row})
        rows.append(row)
        print(head)
    print(f"  ({config.level:.0%} intervals; coverage and diversity: iNEXT-style augmented "
          f"bootstrap over episodes, {config.n_resamples} draws, seed {config.seed}; "
          "novelty: Wilson)")
    shown = novel
    if len(shown):
        print("unique manoeuvres, most frequent first:")
        for r in shown.sort_values("count", ascending=False, kind="stable").head(
                args.examples).itertuples():
            print(f"  {r.count:4d}  {(r.env + ': ') if r.env else ''}{r.label}   e.g. "
                  f"{r.example_scenario}")
    if args.output:
        outputs = {out: pd.DataFrame(rows)}
        if not args.vocabulary:  # a corpus: its novel labels, possibly none
            outputs[novel_path] = novel
        write_tables(outputs)  # together or not at all
        print("wrote " + " and ".join(map(str, outputs)))
    return 0


def diversity_text(row) -> str:
    """Hill numbers and completeness of a diversity row, "at least" where not estimable."""
    at = f"{row['size']} episodes"
    hill = ", ".join(f"q{q} {row[f'hill_q{q}']:.1f}" for q in (0, 1, 2))
    if row["hill_is_bound"]:
        hill = "at least " + hill
    if row.get("hill_order_broken", False):
        hill += " (estimates rise with q: out of order, intervals widened)"
    asym = ", ".join("–" if row[f"asymptote_q{q}"] != row[f"asymptote_q{q}"] else
                     f"{row[f'asymptote_q{q}']:.1f}" for q in (0, 1, 2))
    if row.get("asymptote_order_broken", False):
        asym += " (out of order: not reported)"
    asym = f"at least {asym} (completeness too low to estimate)" if row["asymptote_is_bound"] \
        else asym
    return (f"diversity at {at}: {hill}; sample completeness {row['completeness']:.0%}; "
            f"whole distribution: {asym}")
