"""The page of ``tap-bench agents``: the tables of :mod:`tap_bench.bench.scores.agents` written as
CSV, the performance profiles as a PNG, and ``agents.html`` with a section per agent (what it
covers of the human, what it adds, where it fails) whose scenes link to the run's replay
viewer."""

from __future__ import annotations

import html
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from urllib.parse import quote

import pandas as pd

from tap_bench.bench.scores.agents import (
    HUMAN,
    AgentsResult,
    agents_figures,
    interval_text,
    seed_groups,
)
from tap_bench.errors import FileFormatError
from tap_bench.tableio import atomic_path, write_table

__all__ = ["agents_report_section", "plot_profiles", "write_agents_page"]

_NAMES = {"route_progress": "route progress (IQM)",
          "crashed_at_fault": "at-fault collisions (rate)", "off_road": "off-road (rate)"}


def plot_profiles(profiles: pd.DataFrame, path: str | os.PathLike, *, level: float,
                  unit: str = "run") -> Path:
    """The route-progress performance profiles, one line per agent with its band, as PNG;
    the title says what the bands' bootstrap resampled (``unit``, as
    :func:`~tap_bench.bench.scores.agents.agents_figures`' : ``"run"`` whole training seeds,
    ``"task"`` the seeds of each scene, rliable's stratified bootstrap)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=100)
    for agent, rows in profiles.groupby("agent", sort=False):
        line, = ax.plot(rows["tau"], rows["share"], label=agent, drawstyle="steps-post")
        ax.fill_between(rows["tau"], rows["low"], rows["high"], step="post", alpha=0.2,
                        color=line.get_color())
    ax.set_xlabel("route progress tau")
    ax.set_ylabel("share of runs x scenes with progress > tau")
    ax.set_ylim(-0.02, 1.02)
    what = "bootstrap over whole seeds" if unit == "run" else "stratified bootstrap"
    ax.set_title(f"Performance profiles ({level:.0%} bands, {what})")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return path


def _link(scenario_id: str, viewer: str) -> str:
    return (f'<a href="{viewer}#ep={quote(scenario_id, safe="")}&amp;b={HUMAN}">'
            f"{html.escape(scenario_id)}</a>")


def _section(agent: str, result: AgentsResult, viewer: str) -> str:
    """One agent's section: its figures, coverage, unique manoeuvres and failures."""
    parts = [f"<h2 id=\"agent-{html.escape(agent)}\">{html.escape(agent)}</h2><ul>"]
    for row in result.aggregates[result.aggregates["agent"] == agent].to_dict("records"):
        parts.append(f"<li>{_NAMES.get(row['measure'], row['measure'])}: "
                     f"{interval_text(row)} over {row['runs']} run(s) x {row['scenes']} "
                     "scene(s)</li>")
    cover = result.coverage[(result.coverage["agent"] == agent)
                            & (result.coverage["run"] != "(mean over runs)")]
    for row in cover.to_dict("records"):
        parts.append(f"<li>covers {row['covered']:.0f} of the human's "
                     f"{row['human_manoeuvres']:.0f} manoeuvres in the same scenes "
                     f"({row['coverage']:.0%}; run {html.escape(str(row['run']))})</li>")
    parts.append("</ul>")
    unique = result.unique[result.unique["agent"] == agent]
    if len(unique):
        parts.append("<p>What it adds (manoeuvres no human performed in that scene):</p><ul>")
        for row in unique.to_dict("records"):
            links = ", ".join(_link(e, viewer) for e in str(row["episodes"]).split(", "))
            parts.append(f"<li>{html.escape(row['manoeuvre'])} ({row['runs']} run-scene(s)): "
                         f"{links}</li>")
        parts.append("</ul>")
    failing = result.safety[(result.safety["agent"] == agent)
                            & ((result.safety["at_fault"] > 0) | (result.safety["off_road"] > 0))]
    if len(failing):
        parts.append("<p>Where it fails (by its own label when the episode ended):</p><ul>")
        for row in failing.to_dict("records"):
            parts.append(f"<li>{html.escape(row['kind'])} {html.escape(row['label'])}: "
                         f"{row['at_fault']:.0f} at-fault collision(s), {row['off_road']:.0f} "
                         f"off-road, of {row['episodes']} episode(s) showing it</li>")
        parts.append("</ul>")
        ended = result.scores[(result.scores["agent"] == agent)
                              & ((result.scores["crashed_at_fault"] > 0)
                                 | (result.scores["off_road"] > 0))]
        parts.append("<p>Those episodes: " + ", ".join(
            _link(s, viewer) for s in ended["scenario_id"]) + "</p>")
    else:
        parts.append("<p>No at-fault collision and never off the road.</p>")
    return "\n".join(parts)


def write_agents_page(result: AgentsResult, folder: str | os.PathLike, *,
                      viewer: str = "../viewer/index.html") -> Path:
    """Write the tables (``<name>.csv``), ``profiles.png`` and ``agents.html`` in ``folder``;
    ``viewer``: the replay viewer's page relative to ``folder``. Returns the page's path."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for name, table in result.tables().items():
        write_table(table, folder / f"{name}.csv")
    if len(result.profiles):
        plot_profiles(result.profiles, folder / "profiles.png", level=result.level,
                      unit=result.unit)
    agents = sorted(dict.fromkeys(result.scores["agent"]), key=lambda a: (a != HUMAN, a))
    improvement = result.improvement.copy()
    if len(improvement):
        improvement["P(agent > over)"] = [interval_text(r) for r in improvement.to_dict("records")]
        improvement = improvement.pivot_table(index=["measure", "agent"], columns="over",
                                              values="P(agent > over)", aggfunc="first")
    aggregates = result.aggregates.copy()
    if len(aggregates):
        aggregates["figure"] = [interval_text(r) for r in aggregates.to_dict("records")]
        aggregates = aggregates.pivot_table(index="agent", columns="measure", values="figure",
                                            aggfunc="first").reindex(agents)
    body = [
        "<!doctype html><meta charset=\"utf-8\"><title>Agents on real scenes</title>",
        "<h1>Agents on real scenes</h1>",
        f"<p>Figures over training seeds x scenes (rliable): route progress by its "
        f"interquartile mean, rates by their mean, each with its {result.level:.0%} "
        f"bootstrap interval over training seeds ({result.n_resamples} resamples of "
        + ("whole seeds, every scene of a drawn seed together" if result.unit == "run" else
           "the seeds of each scene on their own (stratified)")
        + "; the scenes fixed). An agent of one run (IDM, lane keeping, random, the human) "
        "has no spread over seeds. Measured coverage of these intervals: docs/agents.md.</p>",
        aggregates.to_html(escape=True) if len(aggregates) else "",
        "<h2>Probability of improvement</h2><p>P(agent > over): a run of the row's agent "
        "beats a run of the column's on a scene drawn at random (ties a half); at-fault "
        "collisions: fewer is better.</p>",
        improvement.to_html(escape=True) if len(improvement) else "",
        "<h2>Performance profiles</h2>" + (
            "<img src=\"profiles.png\" alt=\"performance profiles of route progress\">"
            if len(result.profiles) else "<p>No scene where the human moved: no route "
            "progress to profile.</p>"),
        *[_section(agent, result, viewer) for agent in agents],
    ]
    page = folder / "agents.html"
    with atomic_path(page) as tmp:
        tmp.write_text("\n".join(body), encoding="utf-8")
    return page


def agents_report_section(folder: str | os.PathLike, episodes: pd.DataFrame, *,
                          reference: str, level: float, viewer: str | None,
                          groups: Mapping[str, Sequence[str]] | None = None) -> list[str]:
    """The ``bench run`` report's section on agents of several training seeds: when the run
    is on recorded scenes with the human as its reference and some of its policies are the
    seeds of an agent (a policy of kind ``seeds``), the figures of ``tap-bench agents`` over
    the run's scenes (every agent of the run; the seeds gathered into their agent) as a
    table, the performance profiles, and the whole page written to ``folder/agents/``.
    Empty otherwise (HTML fragments, in order).

    Args:
        folder: the run folder being written (its ``episodes`` and ``segments`` tables).
        episodes: the run's episode table.
        reference: the run's reference policy (the human: ``log``).
        level: the run's two-sided interval level.
        viewer: the replay viewer's page relative to ``folder`` (None: no viewer).
        groups: agent -> its seed policies (default: every group defined,
            :func:`~tap_bench.bench.scores.agents.seed_groups`).
    """
    if reference != HUMAN or "route_progress" not in episodes.columns:
        return []
    policies = set(episodes["policy"].astype(str))
    groups = {agent: tuple(seeds) for agent, seeds in
              (seed_groups() if groups is None else groups).items() if policies & set(seeds)}
    if not groups:
        return []
    try:
        result = agents_figures(folder, groups=groups, level=level)
    except FileFormatError as err:  # e.g. no segment table: say so, keep the report
        return ["<h2>Agents over training seeds</h2>",
                f"<p>Not computed: {html.escape(str(err))}</p>"]
    page = write_agents_page(result, Path(folder) / "agents",
                             viewer="../" + (viewer or "viewer/index.html"))
    agents = sorted(dict.fromkeys(result.scores["agent"]), key=lambda a: (a != HUMAN, a))
    table = result.aggregates.copy()
    table["figure"] = [interval_text(r) for r in table.to_dict("records")]
    table["measure"] = [_NAMES.get(m, m) for m in table["measure"]]
    wide = table.pivot_table(index="agent", columns="measure", values="figure",
                             aggfunc="first").reindex(agents)
    wide.columns.name = None
    names = ", ".join(f"{html.escape(a)} ({len(s)} seeds)" for a, s in groups.items())
    return [
        "<h2>Agents over training seeds</h2>",
        f"<p class=\"note\">An agent of several training seeds is the set of its seeds "
        f"(SPEC 10): {names}. Route progress by its interquartile mean over seeds x scenes, "
        f"rates by their mean, with {level:.0%} bootstrap intervals over whole training "
        "seeds (docs/agents.md measures how often they cover); the other policies are "
        "agents of one run. The coverage of the human, unique manoeuvres, safety by the "
        "agent's own label and the probability of improvement: "
        f"<a href=\"agents/{page.name}\">agents/{page.name}</a> (as "
        "<code>tap-bench agents</code> writes it).</p>",
        wide.to_html(escape=True),
        *(["<img src=\"agents/profiles.png\" alt=\"performance profiles of route progress\">"]
          if len(result.profiles) else []),
    ]
