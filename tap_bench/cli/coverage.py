"""``tap-bench coverage``: behaviour coverage and unique manoeuvres of an agent."""

from __future__ import annotations

import argparse

from tap_bench.sdl import LEVELS
from tap_bench.stats.bootstrap import add_bootstrap_arguments, bootstrap_from_args


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
        "are those of 'bench run'. Each figure is scored on whole labels and on the "
        "manoeuvres (segment labels) the episodes contain, and stands beside the "
        "same-policy figure (the reference split in halves, one held against the other) "
        "with the difference from it and its interval.")
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
    p.add_argument("--window", default="auto",
                   help="cut the agent's episodes into windows of this many seconds before "
                   "labelling: 'auto' (default) the reference's median track length when "
                   "both are trajectory tables (WOMD: 9.1 s tracks, so 30 s episodes are "
                   "not held against 9 s tracks), 'none' whole episodes")
    p.add_argument("--examples", type=int, default=10, help="novel labels listed (10)")
    add_bootstrap_arguments(p)
    p.add_argument("-o", "--output", help="write the coverage and novelty rows here "
                   "(.csv/.parquet); the novel labels go beside it as <name>.novel.<suffix>")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    import pandas as pd

    from tap_bench.bench.episodes import episodes_from_table
    from tap_bench.bench.scores import windows as win
    from tap_bench.bench.scores.coverage import UNITS, corpus_reference, vocabulary_reference
    from tap_bench.bench.scores.diversity import diversity_table
    from tap_bench.bench.scores.scoring import reference_scores
    from tap_bench.labelling import tap
    from tap_bench.labels import label_text
    from tap_bench.sdl import check_axes
    from tap_bench.tableio import check_outputs, episodes_path, read_table, write_tables

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
    ref_table = None if args.vocabulary else read_table(args.reference)
    window = None if ref_table is None else win.window_seconds(args.window, ref_table, table)
    if window is not None:  # the agent's episodes cut to the reference's track length
        table = win.number_windows(win.windows(table, window))
    episodes, _, _ = episodes_from_table(table.assign(policy=name), level=args.level,
                                         thresholds=args.thresholds, policy=name,
                                         source=str(args.agent), interactions=inter)
    episodes = episodes.assign(sdl=label_text(episodes, axes))  # the label on the axes
    if window is not None:  # the episode each window was cut from: resampled whole
        episodes[win.CUT_FROM] = win.window_episode(episodes["scenario_id"])
    agent_envs = sorted(set(episodes["env"]))
    if args.vocabulary:
        references = [vocabulary_reference(args.level, axes=axes)]
        ref_name = f"{args.level} vocabulary"
    else:
        if "sdl" not in ref_table.columns:
            ref_table = tap(ref_table, args.thresholds, source=str(args.reference),
                            interactions="all" if inter else None).labels(args.level)
        ref_name = Path(args.reference).name
        keyed = "env" in ref_table.columns and set(agent_envs) <= set(
            ref_table["env"].unique()) and agent_envs != [""]  # rollouts: (env, label)
        references = [
            {env: corpus_reference(ref_table[ref_table["env"] == env], args.level,
                                   tracks=args.reference_tracks, name=f"{ref_name} ({env})",
                                   axes=axes, unit=unit) for env in agent_envs}
            if keyed else corpus_reference(ref_table, args.level,
                                           tracks=args.reference_tracks, axes=axes,
                                           name=ref_name, unit=unit)
            for unit in UNITS]
    unit_of = {"episodes": f"{window:.1f} s windows" if window is not None else "episodes"}
    unit_of["segments"] = (f"{unit_of['episodes']}, segments" if window is not None
        else "segments")
    parts = [reference_scores(
        episodes, ref, ref_name, config=config,
        unit=unit_of[(next(iter(ref.values())) if isinstance(ref, dict) else ref).unit],
        windowed=window is not None)
        for ref in references]
    cov, nov, novel = (pd.concat([p[i] for p in parts if len(p[i])], ignore_index=True)
                       if any(len(p[i]) for p in parts) else parts[0][i] for i in range(3))
    div = diversity_table(episodes, config)
    ok = episodes[(episodes["status"] == "ok") & episodes["sdl"].notna()]
    described = "; ".join(r.description for ref in references for r in (
        ref.values() if isinstance(ref, dict) else [ref]))
    cut = "" if window is None else f" (its episodes cut into {window:.1f} s windows)"
    print(f"{name}: {len(ok)} {unit_of['episodes']} with an ego label at level "
          f"{args.level}{cut}; reference: {described}")
    rows = []
    for r in cov.itertuples(index=False):
        d = div[div["env"] == r.env].iloc[0] if (div["env"] == r.env).any() else None
        head = (f"  {r.env or 'all'}, {r.unit}: coverage {r.coverage:.1%} "
                f"[{r.coverage_low:.1%}, {r.coverage_high:.1%}], weighted "
                f"{r.weighted_coverage:.1%} [{r.weighted_low:.1%}, {r.weighted_high:.1%}]")
        row = r._asdict()
        if "null_coverage" in row and row["null_coverage"] == row["null_coverage"]:
            head += "; " + null_text(row, "coverage", "half_coverage", "null_coverage",
                                     "coverage_diff")
        if d is not None and r.unit == unit_of["episodes"]:
            head += f"; {diversity_text(d)}"
            row.update({k: d[k] for k in div.columns if k not in ("env", "policy", "n")})
        match = nov[(nov["env"] == r.env) & (nov["unit"] == r.unit)] if len(nov) else nov
        if len(match):
            v = match.iloc[0]
            head += (f"; unique manoeuvres {v['novel_rate']:.1%} [{v['novel_low']:.1%}, "
                     f"{v['novel_high']:.1%}] of {unit_of['episodes']}, "
                     f"{int(v['n_novel_labels'])} labels")
            if "null_novel_rate" in v and v["null_novel_rate"] == v["null_novel_rate"]:
                head += "; " + null_text(v, "novel", "half_novel_rate", "null_novel_rate",
                                         "novel_diff")
            row.update({k: v[k] for k in nov.columns if k not in row})
        rows.append(row)
        print(head)
    print(f"  ({config.level:.0%} intervals; coverage and diversity: iNEXT-style augmented "
          f"bootstrap over episodes, {config.n_resamples} draws, seed {config.seed}; "
          "novelty: Wilson; the same-policy figure: the reference split in random halves, "
          "one half held against the other, beside the agent at the same sizes, the "
          "difference's interval a bootstrap over splits (docs/benchmark.md))")
    if len(novel):
        print("unique manoeuvres, most frequent first:")
        for r in novel.sort_values("count", ascending=False, kind="stable").head(
                args.examples).itertuples():
            print(f"  {r.count:4d}  {(r.env + ': ') if r.env else ''}{r.label} "
                  f"({r.unit})   e.g. {r.example_scenario}")
    if args.output:
        outputs = {out: pd.DataFrame(rows)}
        if not args.vocabulary:  # a corpus: its novel labels, possibly none
            outputs[novel_path] = novel
        write_tables(outputs)  # together or not at all
        print("wrote " + " and ".join(map(str, outputs)))
    return 0


def null_text(row, what: str, half: str, null: str, diff: str) -> str:
    """``same-policy coverage 21.0% (halves of 15), agent 12.0%: -9.0 pts [-20.1, +2.3]``:
    the same-policy figure, the agent at the same sizes, the difference and its interval."""
    return (f"same-policy {what} {row[null]:.1%} (halves of {int(row['null_m'])}), agent "
            f"{row[half]:.1%}: {100 * row[diff]:+.1f} pts [{100 * row[diff + '_low']:+.1f}, "
            f"{100 * row[diff + '_high']:+.1f}]")


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
    asym = (f"at least {asym} (completeness too low to estimate)" if row["asymptote_is_bound"]
        else asym)
    return (f"diversity at {at}: {hill}; sample completeness {row['completeness']:.0%}; "
            f"whole distribution: {asym}")
