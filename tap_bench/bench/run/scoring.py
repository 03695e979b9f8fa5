"""The scoring of a suite run, every score of the run in one call (:func:`score_run`):
:func:`tap_bench.bench.scores.scoring.score` with each reference's scenarios matched to the
episodes (the references as :mod:`~tap_bench.bench.run.references` read them), windows of
its tracks' length, the gate's power, the interaction contexts and the sim-to-real gap of
every policy (part of :mod:`tap_bench.bench.run.runner`)."""

from __future__ import annotations

from collections.abc import Iterator

import pandas as pd

from tap_bench.bench.gate.power import power_table
from tap_bench.bench.run.plan import SuitePlan
from tap_bench.bench.run.references import Corpora
from tap_bench.bench.run.spill import SpilledTable
from tap_bench.bench.run.tasks import RunTables, Spilled
from tap_bench.bench.scores.contexts import context_scores
from tap_bench.bench.scores.gap import gap_scores
from tap_bench.bench.scores.scenarios import match_scenarios
from tap_bench.bench.scores.scoring import Scores, score
from tap_bench.bench.scores.windows import window_episodes, window_seconds
from tap_bench.thresholds import Thresholds

__all__ = ["score_run"]


def score_run(plan: SuitePlan, tables: RunTables, corpora: Corpora) -> Scores:
    """Every score of the run: :func:`~tap_bench.bench.scores.scoring.score` of its
    episodes, given what the run adds to it: the scenarios matched to each reference,
    windows of its tracks' length, the gate's power, the interaction contexts and the
    sim-to-real gaps. A pure function of the run's tables (the runner reads the scores of
    an unchanged run back from the cache instead)."""
    episodes, level, config = tables.episodes, plan.level, plan.bootstrap
    matches, unmatched = _scenario_matches(corpora, tables.labels, tables.trajectories,
                                           level)
    egos = _gap_egos(corpora, tables.labels, episodes, level)
    windows = _windows(corpora, tables.trajectories, level, plan.thresholds)
    power = power_table(episodes, plan.gate, cells=len(plan.envs) * len(plan.definitions))
    # the interaction contexts, scored as `tap-bench contexts` scores them
    contexts = context_scores(tables.occurrences, list(pd.unique(episodes["policy"])),
                              plan.reference, config=config)
    gap = gap_labels = None
    gap_methods: dict[str, str] = {}
    if egos is not None:  # the sim-to-real gap of every policy from each data reference
        real = {name: traj for name, (traj, _) in corpora.items() if traj is not None}
        gap, gap_labels, gap_methods = gap_scores(egos, real, level, plan.thresholds, config)
    methods = {}  # how these were made, after the methods of score's own tables
    if len(contexts):
        methods["contexts"] = (
            "each policy against the reference inside each interaction context (trend "
            "level): per episode the context's measures reduced over its occurrences, "
            "then paired by seed (t; Tango for a share) where both meet the context, "
            "else unpaired (Welch; Newcombe), as tap-bench contexts")
    if unmatched:
        methods["scenario matching skipped"] = (
            f"{', '.join(unmatched)}: the data marks no ego vehicle (is_ego), so its "
            "scenarios cannot be matched by what happens around the ego; coverage and "
            "novelty use all its vehicles")
    return score(episodes, reference_policy=plan.reference, level=level, config=config,
                 references={name: lab for name, (_, lab) in corpora.items()} or None,
                 scenario_matches=matches, gate_power=power, windows=windows or None,
                 contexts=contexts, gap=gap, gap_labels=gap_labels,
                 methods={**methods, **gap_methods})


EPISODES_AT_ONCE = 16
"""Episodes of a spilled run matched against a reference's scenarios in one call."""


def _episode_groups(labels: Spilled, trajectories: Spilled | None
                    ) -> Iterator[tuple[pd.DataFrame, pd.DataFrame | None]]:
    """The run's labels and trajectories a few episodes at a time (a spilled run's parts,
    :data:`EPISODES_AT_ONCE` episodes a group, in run order), or whole."""
    if not isinstance(labels, SpilledTable):
        yield labels, (trajectories if not isinstance(trajectories, SpilledTable)
                       else trajectories.table())
        return
    indices = sorted(labels.spill.parts["labels"])
    for start in range(0, len(indices), EPISODES_AT_ONCE):
        group = indices[start:start + EPISODES_AT_ONCE]
        yield labels.table(group), (trajectories.table(group)
                                    if isinstance(trajectories, SpilledTable) else trajectories)


def _scenario_matches(corpora: Corpora, labels: Spilled, trajectories: Spilled | None,
                      level: str) -> tuple[pd.DataFrame | None, list[str]]:
    """Each episode's best-matching scenarios of every reference with trajectories (None:
    none), and the references that could not be matched (their data mark no ego). A
    spilled run's episodes are matched a group at a time (each episode's matches are its
    own: the rows of one call on every episode)."""
    matches, unmatched = [], []
    for name, (ref_traj, ref_labels) in corpora.items():
        if ref_traj is not None and len(labels):
            if "is_ego" not in ref_labels.columns:  # a format without an ego
                unmatched.append(name)
                continue
            found = [match_scenarios(mine, traj, ref_labels, ref_traj, level=level, top=3)
                     for mine, traj in _episode_groups(labels, trajectories)]
            table = pd.concat([f for f in found if len(f)] or found[:1], ignore_index=True)
            matches.append(table.assign(reference=name))
    return (pd.concat(matches, ignore_index=True) if matches else None), unmatched


def _egos(trajectories: SpilledTable) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(the egos' rows, the first and last time of every track): what the windows need of
    a spilled run's trajectories, read an episode at a time."""
    egos, spans = [], []
    for i in sorted(trajectories.spill.parts["trajectories"]):
        table = trajectories.table([i])
        egos.append(table[table["is_ego"].fillna(False).to_numpy(bool)]
                    if "is_ego" in table.columns else table)
        by_track = table.groupby(["scenario_id", "track_id"], sort=False)["t"]
        spans.append(pd.concat([by_track.min(), by_track.max()]).reset_index())
    return pd.concat(egos, ignore_index=True), pd.concat(spans, ignore_index=True)


def _windows(corpora: Corpora, trajectories: Spilled | None, level: str,
             thresholds: Thresholds) -> dict[str, tuple[pd.DataFrame, str]]:
    """Coverage and novelty against real driving: the episodes cut in windows of the
    length of each reference's tracks, by reference name (only the egos are cut, and
    only their rows are read together)."""
    cut: dict[str, tuple[pd.DataFrame, str]] = {}
    if trajectories is None or not any(t is not None for t, _ in corpora.values()):
        return cut
    egos, spans = (_egos(trajectories) if isinstance(trajectories, SpilledTable)
                   else (trajectories, trajectories))
    for name, (ref_traj, _) in corpora.items():
        if ref_traj is not None:
            seconds = window_seconds("auto", ref_traj, spans)
            if seconds is not None:
                cut[name] = (window_episodes(egos, seconds, level,
                                             thresholds=thresholds, source=name),
                             f"{seconds:.1f} s windows")
    return cut


def _gap_egos(corpora: Corpora, labels: Spilled, episodes: pd.DataFrame, level: str
              ) -> pd.DataFrame | None:
    """What the sim-to-real gaps compare with each reference given as driving-data files:
    the egos' labels at the suite's level with each episode's ``mean_speed``; None when
    there is no such reference or the labels mark no ego."""
    if not any(traj is not None for traj, _ in corpora.values()) or not len(labels):
        return None
    egos = _ego_labels(labels, level)
    if egos is None:
        return None
    speeds = episodes[["env", "policy", "seed", "mean_speed"]]
    return egos.drop(columns=["mean_speed"], errors="ignore").merge(
        speeds, on=["env", "policy", "seed"], how="left")


def _ego_labels(labels: Spilled, level: str) -> pd.DataFrame | None:
    """The egos' labels at ``level`` (a spilled run's read a group of episodes at a time);
    None: the labels mark no ego."""
    mine = []
    for part, _ in _episode_groups(labels, None):
        if "is_ego" not in part.columns:
            return None
        mine.append(part[(part["level"] == level) & part["is_ego"].fillna(False)])
    return pd.concat(mine) if len(mine) > 1 else mine[0]
