"""Agents on real scenes, judged as rliable recommends and by the human behaviour they cover
(SPEC section 10): ``tap-bench agents``.

**Agents and their runs.** A policy definition of kind ``seeds`` names a policy that stands
for several trained seeds (``policies/ppo-womd.json``: ``{"kind": "seeds", "params":
{"seeds": ["ppo-womd-grid-seed0", "ppo-womd-grid-seed1", "ppo-womd-grid-seed2"]}}``). In a
run folder (``bench run`` on recorded scenes) every policy that is a seed of such a group is
a run of that agent; any other policy is an agent of one run (IDM, lane keeping, random,
the human ``log``: one episode per scene). A task is a scene (env and scene index).

**Figures**, from the run's ``episodes.parquet`` and ``segments.parquet``:

- ``scores``: one row per (agent, run, scene): route progress, at-fault collision, any
  collision, off-road.
- ``aggregates``: per agent and measure, over runs x scenes: route progress by its
  interquartile mean, the rates (at-fault collisions, off-road) by their mean, each with its
  bootstrap interval over training seeds (:mod:`tap_bench.stats.aggregate`; whole seeds
  resampled, or with ``unit="task"`` rliable's stratified bootstrap). Route progress is taken on
  the scenes where the human moved (it is NaN elsewhere).
- ``improvement``: P(X > Y) of every agent over every other, on route progress (higher is
  better) and on at-fault collisions (fewer is better), with intervals.
- ``profiles``: the route progress run-score distribution with pointwise bands.
- ``coverage``: the share of the human's manoeuvres (maneuver-level labels of the ego, per
  axis, and its interaction contexts: ``lateral: Left Turn``, ``interaction: Following``)
  that the agent performs in the same scene, pooled over scenes, per run and for the agent
  (mean over runs).
- ``unique``: manoeuvres an agent performs in a scene where the human did not, with the
  scenes and how many runs did so.
- ``safety``: per the agent's own label (its maneuver-level label, lateral | longitudinal,
  and its interaction context at the time): how many of its episodes showed it and how many
  ended in an at-fault collision or off the road while it was its label (the label of the
  ego's segment at the episode's end).
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from tap_bench.errors import FileFormatError, ParameterError
from tap_bench.sim.policies import SeedGroupError, expand_seed_groups, seed_group, seed_groups
from tap_bench.stats.aggregate import (
    Interval,
    iqm,
    mean_score,
    performance_profile,
    probability_of_improvement,
    stratified_bootstrap,
)
from tap_bench.stats.bootstrap import named_rng

__all__ = ["HUMAN", "PROFILE_THRESHOLDS", "AgentsResult", "SeedGroupError", "agent_of",
           "agents_figures", "expand_seed_groups", "seed_group", "seed_groups", "seeds_text"]

HUMAN = "log"
"""The policy that replays the recorded ego: the human, the reference of coverage."""
PROFILE_THRESHOLDS = np.linspace(0.0, 1.0, 21)
"""The route-progress thresholds tau of the performance profiles."""
MEASURES = {  # measure -> (aggregate, higher is better)
    "route_progress": ("iqm", True),
    "crashed_at_fault": ("mean", False),
    "off_road": ("mean", False),
}


def agent_of(policy: str, groups: Mapping[str, Sequence[str]]) -> str:
    """The agent a policy is a run of: its group, else itself."""
    for agent, seeds in groups.items():
        if policy in seeds:
            return agent
    return policy


@dataclass(frozen=True)
class AgentsResult:
    """The tables of :func:`agents_figures` (see the module docstring for each)."""

    scores: pd.DataFrame
    aggregates: pd.DataFrame
    improvement: pd.DataFrame
    profiles: pd.DataFrame
    coverage: pd.DataFrame
    unique: pd.DataFrame
    safety: pd.DataFrame
    level: float
    n_resamples: int
    unit: str = "run"

    def tables(self) -> dict[str, pd.DataFrame]:
        """name -> table, as written."""
        return {name: getattr(self, name) for name in (
            "scores", "aggregates", "improvement", "profiles", "coverage", "unique", "safety")}


def _read(run: Path, name: str) -> pd.DataFrame:
    path = run / f"{name}.parquet"
    if not path.is_file():
        raise FileFormatError(f"{run}: no {name}.parquet; give the folder of a 'bench run' "
                              "(on recorded scenes) or run one with 'tap-bench agents --womd'.")
    return pd.read_parquet(path)


def _scene(scenario_id: pd.Series) -> pd.Series:
    """The scene's id of an episode's ``scenario_id`` (``"<scene>/<policy>"``)."""
    return scenario_id.astype(str).str.rsplit("/", n=1).str[0]


def _episodes(run: Path, groups: Mapping[str, Sequence[str]]) -> pd.DataFrame:
    """The run's finished episodes on recorded scenes, with their agent and scene."""
    episodes = _read(run, "episodes")
    if "route_progress" not in episodes.columns:
        raise FileFormatError(f"{run}: its episodes have no route_progress: 'tap-bench "
                              "agents' judges agents on recorded scenes (a suite with "
                              "\"envs\": [{\"womd\": ...}]).")
    ok = episodes[episodes["status"] == "ok"].copy()
    if HUMAN not in set(ok["policy"]):
        raise FileFormatError(f"{run}: the human (policy {HUMAN!r}) has no episode; add it "
                              "to the suite's policies: it is the reference.")
    ok["agent"] = [agent_of(p, groups) for p in ok["policy"]]
    ok["scene"] = _scene(ok["scenario_id"])
    ok["task"] = ok["env"].astype(str) + ":" + ok["seed"].astype(str)
    for column in ("crashed_at_fault", "off_road", "crashed"):
        ok[column] = ok[column].astype(float)
    return ok


def _matrix(scores: pd.DataFrame, agent: str, measure: str, tasks: Sequence[str]
            ) -> np.ndarray:
    """``(n_runs, n_tasks)`` scores of one agent (higher better: costs negated)."""
    table = scores[scores["agent"] == agent].pivot_table(
        index="policy", columns="task", values=measure, aggfunc="first")
    table = table.reindex(columns=list(tasks))
    values = table.to_numpy(float)
    return values if MEASURES[measure][1] else -values


def _tasks(scores: pd.DataFrame, measure: str) -> list[str]:
    """The tasks every run of every agent has a score of ``measure`` on."""
    table = scores.pivot_table(index="policy", columns="task", values=measure,
                               aggfunc="first")
    return [t for t in table.columns if table[t].notna().all()]


def _aggregates(scores: pd.DataFrame, agents: Sequence[str], *, seed: int, level: float,
                n_resamples: int, unit: str) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """The aggregates, improvement and profile tables."""
    rows, pairs, profiles = [], [], []
    for measure, (kind, higher) in MEASURES.items():
        tasks = _tasks(scores, measure)
        if not tasks:
            continue
        stat = iqm if kind == "iqm" else mean_score
        for agent in agents:
            m = _matrix(scores, agent, measure, tasks)
            out = stratified_bootstrap(m, stat, rng=named_rng(seed, "agents", measure, agent),
                                       level=level, n_resamples=n_resamples, unit=unit)
            sign = 1.0 if higher else -1.0
            # every measure here is a share in [0, 1]; the widened draws may pass its ends
            low, high = (min(max(v, 0.0), 1.0)
                         for v in sorted((sign * out.low, sign * out.high)))
            rows.append({"agent": agent, "measure": measure, "aggregate": kind,
                         "estimate": sign * out.estimate + 0.0, "low": low + 0.0,
                         "high": high + 0.0,
                         "runs": m.shape[0], "scenes": m.shape[1]})
        for a in agents:
            for b in agents:
                if a == b:
                    continue
                out = probability_of_improvement(
                    _matrix(scores, a, measure, tasks), _matrix(scores, b, measure, tasks),
                    rng=named_rng(seed, "improvement", measure, a, b), level=level,
                    n_resamples=n_resamples, unit=unit)
                pairs.append({"agent": a, "over": b, "measure": measure,
                              "probability": out.estimate, "low": out.low, "high": out.high,
                              "scenes": len(tasks)})
        if kind == "iqm":  # a score in [0, 1] (route progress): its run-score distribution
            for agent in agents:
                share, low, high = performance_profile(
                    _matrix(scores, agent, measure, tasks), PROFILE_THRESHOLDS,
                    rng=named_rng(seed, "profile", measure, agent), level=level,
                    n_resamples=n_resamples, unit=unit)
                profiles += [{"agent": agent, "measure": measure, "tau": float(t),
                              "share": float(s), "low": float(lo), "high": float(hi)}
                             for t, s, lo, hi in zip(PROFILE_THRESHOLDS, share, low, high,
                                                     strict=True)]
    return pd.DataFrame(rows), pd.DataFrame(pairs), pd.DataFrame(profiles)


_TRACK_ID = re.compile(r"\s*\(.*\)$")


def _ego_items(run: Path, episodes: pd.DataFrame) -> pd.DataFrame:
    """The ego's maneuver-level segments of every episode: ``scenario_id``, ``item``
    (``"axis: label"``, interaction relations without the other's track id), ``t_start``,
    ``t_end``, ``label`` (the bare label), ``axis``."""
    segments = _read(run, "segments")
    ego = segments[segments["is_ego"].astype(bool) & (segments["level"] == "maneuver")
                   & segments["scenario_id"].isin(set(episodes["scenario_id"]))].copy()
    ego["label"] = ego["label"].astype(str).str.replace(_TRACK_ID, "", regex=True)
    ego["item"] = ego["axis"].astype(str) + ": " + ego["label"]
    return ego[["scenario_id", "axis", "label", "item", "t_start", "t_end"]]


def _coverage(episodes: pd.DataFrame, items: pd.DataFrame, agents: Sequence[str]
              ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The coverage and unique tables."""
    per_episode = items.groupby("scenario_id")["item"].agg(set)
    eps = episodes.assign(items=[per_episode.get(s, set()) for s in episodes["scenario_id"]])
    human = eps[eps["policy"] == HUMAN].set_index("task")["items"]
    rows, unique = [], {}
    for agent in agents:
        runs = eps[eps["agent"] == agent]
        shares = []
        for policy, run in runs.groupby("policy"):
            shown = total = 0
            for task, own in zip(run["task"], run["items"], strict=True):
                theirs = human.get(task, set())
                shown += len(theirs & own)
                total += len(theirs)
                episode = run[run["task"] == task].iloc[0]
                for item in sorted(own - theirs):
                    entry = unique.setdefault((agent, item), {"scenes": set(), "runs": 0,
                                                              "episodes": []})
                    entry["scenes"].add(str(episode["scene"]))
                    entry["episodes"].append(str(episode["scenario_id"]))
                    entry["runs"] += 1
            share = shown / total if total else float("nan")
            shares.append(share)
            rows.append({"agent": agent, "run": policy, "coverage": share,
                         "human_manoeuvres": total, "covered": shown})
        rows.append({"agent": agent, "run": "(mean over runs)",
                     "coverage": float(np.nanmean(shares)) if shares else float("nan"),
                     "human_manoeuvres": np.nan, "covered": np.nan})
    table = pd.DataFrame(rows)
    uniq = pd.DataFrame([{"agent": a, "manoeuvre": item, "runs": v["runs"],
                          "scenes": ", ".join(sorted(v["scenes"])),
                          "episodes": ", ".join(v["episodes"])}
                         for (a, item), v in unique.items()],
                        columns=["agent", "manoeuvre", "runs", "scenes", "episodes"])
    return table, uniq


def _safety(episodes: pd.DataFrame, items: pd.DataFrame) -> pd.DataFrame:
    """Per agent and own label: episodes showing it, and those that ended in an at-fault
    collision or off the road while it was the ego's label."""
    rows = []
    lateral = items[items["axis"] == "lateral"]
    longitudinal = items[items["axis"] == "longitudinal"]
    interaction = items[items["axis"] == "interaction"]

    def at_end(table: pd.DataFrame, scenario_id: str) -> str | None:
        own = table[table["scenario_id"] == scenario_id]
        return None if own.empty else str(own.sort_values("t_end")["label"].iloc[-1])

    for _, episode in episodes.iterrows():
        sid = episode["scenario_id"]
        manoeuvre = f"{at_end(lateral, sid)} | {at_end(longitudinal, sid)}"
        context = at_end(interaction, sid)
        lat = lateral[lateral["scenario_id"] == sid]
        lon = longitudinal[longitudinal["scenario_id"] == sid]
        shown = {f"{a.label} | {b.label}" for a in lat.itertuples() for b in lon.itertuples()
                 if min(a.t_end, b.t_end) > max(a.t_start, b.t_start)}  # at the same time
        for label in shown | {manoeuvre}:
            rows.append({"agent": episode["agent"], "kind": "manoeuvre", "label": label,
                         "episode": sid, "ended_here": label == manoeuvre,
                         "at_fault": float(episode["crashed_at_fault"]),
                         "off_road": float(episode["off_road"])})
        contexts = set(interaction.loc[interaction["scenario_id"] == sid, "label"])
        for label in contexts | ({context} if context else set()):
            rows.append({"agent": episode["agent"], "kind": "interaction", "label": label,
                         "episode": sid, "ended_here": label == context,
                         "at_fault": float(episode["crashed_at_fault"]),
                         "off_road": float(episode["off_road"])})
    if not rows:
        return pd.DataFrame(columns=["agent", "kind", "label", "episodes", "at_fault",
                                     "off_road", "at_fault_rate"])
    table = pd.DataFrame(rows)
    table["at_fault_here"] = table["ended_here"] & (table["at_fault"] > 0)
    table["off_road_here"] = table["ended_here"] & (table["off_road"] > 0)
    out = table.groupby(["agent", "kind", "label"]).agg(
        episodes=("episode", "nunique"), at_fault=("at_fault_here", "sum"),
        off_road=("off_road_here", "sum")).reset_index()
    out["at_fault_rate"] = out["at_fault"] / out["episodes"]
    return out.sort_values(["agent", "kind", "at_fault", "off_road"],
                           ascending=[True, True, False, False]).reset_index(drop=True)


def agents_figures(run: str | os.PathLike, *, groups: Mapping[str, Sequence[str]] | None = None,
                   level: float = 0.95, n_resamples: int = 2000, seed: int = 0,
                   scenes: Sequence[int] | None = None, unit: str = "run") -> AgentsResult:
    """Every figure of the module docstring for the run folder ``run``.

    Args:
        run: a ``bench run`` folder on recorded scenes, with the human (``log``).
        groups: agent -> its seed policies (default: :func:`seed_groups`).
        level: two-sided level of every interval.
        n_resamples: bootstrap resamples of every interval.
        seed: root seed of the named random streams.
        unit: what the bootstrap resamples (:data:`tap_bench.stats.aggregate.UNITS`): whole
            runs (default: each trained seed drives every scene) or the runs of each scene
            on their own (rliable's stratified bootstrap).
        scenes: only these scenes (their index in the files, the episodes' ``seed``): the
            scenes an agent was not trained on, say; None: every scene.

    Raises:
        FileFormatError: the folder lacks a table, or the human's episodes, or has no
            episode on one of ``scenes``.
    """
    if not 0.5 <= level < 1:
        raise ParameterError("level", level, "a two-sided level in [0.5, 1), e.g. 0.95")
    run = Path(run)
    groups = seed_groups() if groups is None else dict(groups)
    episodes = _episodes(run, groups)
    if scenes is not None:
        wanted = sorted({int(k) for k in scenes})
        have = sorted({int(k) for k in episodes["seed"]})
        missing = [k for k in wanted if k not in have]
        if missing:  # judged on fewer scenes than asked, the figures would say otherwise
            raise FileFormatError(
                f"{run}: no finished episode on scene(s) {seeds_text(missing)} of the "
                f"{seeds_text(wanted)} asked; the run has scenes {seeds_text(have)}. A scene "
                "is its index in the files the run read, in their order, as 'tap-bench train "
                "--hold-out' counts them in its own files: run the agent's training files "
                "(tap-bench agents RUN --womd FILES), or name scenes the run has.")
        episodes = episodes[episodes["seed"].isin(wanted)]
    agents = sorted(set(episodes["agent"]), key=lambda a: (a != HUMAN, a))
    scores = episodes[["agent", "policy", "env", "seed", "scene", "task", "scenario_id",
                       "route_progress", "crashed_at_fault", "crashed", "off_road"]]
    scores = scores.sort_values(["agent", "policy", "task"]).reset_index(drop=True)
    aggregates, improvement, profiles = _aggregates(scores, agents, seed=seed, level=level,
                                                    n_resamples=n_resamples, unit=unit)
    items = _ego_items(run, episodes)
    coverage, unique = _coverage(episodes, items, agents)
    safety = _safety(episodes, items)
    return AgentsResult(scores, aggregates, improvement, profiles, coverage, unique, safety,
                        level, n_resamples, unit)


def seeds_text(seeds: Sequence[int]) -> str:
    """Sorted scene indices as runs: ``[0, 1, 2, 3, 7]`` -> ``"0-3,7"``."""
    runs: list[list[int]] = []
    for k in seeds:
        if runs and k == runs[-1][-1] + 1:
            runs[-1].append(k)
        else:
            runs.append([k])
    return ",".join(f"{r[0]}-{r[-1]}" if len(r) > 2 else ",".join(map(str, r)) for r in runs)


def interval_text(row: Mapping[str, float], digits: int = 2) -> str:
    """``"0.83 [0.71, 0.90]"`` of a row with estimate (or probability), low and high."""
    value = row.get("estimate", row.get("probability"))
    return f"{value:.{digits}f} [{row['low']:.{digits}f}, {row['high']:.{digits}f}]"


def as_interval(row: Mapping[str, float], level: float) -> Interval:
    """A table row as an :class:`~tap_bench.stats.aggregate.Interval`."""
    return Interval(float(row.get("estimate", row.get("probability"))), float(row["low"]),
                    float(row["high"]), level)
