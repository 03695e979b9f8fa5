"""The run report: SVG figures and one static HTML page (no server, nothing from the
network).

:func:`write_report` writes ``plots/*.svg`` and ``report.html`` into a run folder. The page
holds its figures inline, so the HTML file alone is the whole report (mail it, open it from
disk); the figure files are there for papers and slides. A small inline script sorts and
searches the long tables; without it the page still reads in full.

The page reads from the top: a summary table of each policy against the reference policy
(every measure with its interval and a better / worse / no-difference mark), then one panel
per env, then the comparisons, coverage and unique manoeuvres in detail. Every figure is
drawn at the size it is shown (text at least 11 px), its scales fitted to the data, its
labels whole; every table gives units and numbers to their precision, shows its first rows
and keeps the rest a click away. When the run has a replay viewer (``viewer/``), the rows
that name episodes or labels link to the replay that shows them.
"""

from __future__ import annotations

import html
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

import pandas as pd

from tap_bench.bench.gate.power import POWER, power_summary
from tap_bench.bench.measures import run_measures
from tap_bench.bench.report.figures import TOP_LABELS, write_plots
from tap_bench.bench.report.pages import timings_html
from tap_bench.bench.report.realism import realism_section
from tap_bench.bench.report.tables import (
    _display_coverage,
    _display_matched,
    _display_measures,
    _display_novel_labels,
    _display_novelty,
    _display_paired,
    _display_paired_labels,
    _display_paired_measures,
    _envs,
    _pct,
    _seed_text,
    _slug,
    _thresholds_text,
    diversity_display,
    html_table,
    level_text,
    summary_table,
)
from tap_bench.bench.scores.scoring import Scores
from tap_bench.tableio import atomic_path

if TYPE_CHECKING:
    from tap_bench.bench.cache import EpisodeCache

__all__ = ["diversity_display", "html_table", "summary_table", "write_plots", "write_report"]

# -- HTML -----------------------------------------------------------------------------------

_CSS = """
body{font-family:system-ui,sans-serif;margin:1.5em auto;max-width:1200px;color:#222;
padding:0 1em;font-size:15px;line-height:1.4}
h1{font-size:1.6em}h2{font-size:1.3em;margin-top:1.8em;border-bottom:1px solid #ccc}
h3{font-size:1.1em;margin:1.2em 0 .3em}
.scroll{overflow-x:auto;max-width:100%}
table{border-collapse:collapse;font-size:13px;margin:.4em 0}
caption{text-align:left;font-size:13px;color:#444;padding:.2em 0;caption-side:top}
th,td{border:1px solid #ddd;padding:.25em .5em;text-align:right;vertical-align:top}
th{background:#f3f3f3;cursor:pointer;white-space:nowrap}
td.l,th.l{text-align:left}td.l{max-width:26em;overflow-wrap:anywhere}
td.better{color:#2b8a3e;font-weight:600}td.worse{color:#c92a2a;font-weight:600}
td.same{color:#666}td.nowrap{white-space:nowrap}td.ref{color:#666;font-style:italic}
tr.more{display:none}table.open tr.more{display:table-row}tr.hidden{display:none !important}
.tools{font-size:13px;margin:.3em 0;display:flex;gap:.8em;align-items:center}
.tools input{font-size:13px;width:18em}
figure{margin:.6em 0}img,figure svg{border:1px solid #eee;max-width:100%;height:auto}
figcaption{font-size:13px;color:#444;max-width:60em}
.note{color:#555;font-size:13px}.fail{color:#a00}
a.replay{white-space:nowrap}
.verdict p{margin:.6em 0 .1em}.verdict ul{margin:.1em 0 .4em;padding-left:1.4em}
.verdict span.worse{color:#c92a2a;font-weight:700;text-transform:uppercase}
.verdict span.better{color:#2b8a3e;font-weight:700;text-transform:uppercase}
.verdict span.same{color:#444;font-weight:600}.note.warning{color:#a05a00}
"""

_SCRIPT = """
document.querySelectorAll('table.long').forEach(function (t) {
  var box = t.closest('.tablebox');
  var search = box.querySelector('input.search'), more = box.querySelector('button.more');
  var rows = Array.prototype.slice.call(t.tBodies[0].rows);
  if (more) more.addEventListener('click', function () {
    t.classList.toggle('open');
    more.textContent = t.classList.contains('open') ? 'show first rows only'
                                                     : 'show all ' + rows.length + ' rows';
  });
  if (search) search.addEventListener('input', function () {
    var q = search.value.toLowerCase();
    if (q && !t.classList.contains('open') && more) more.click();
    rows.forEach(function (r) {
      r.classList.toggle('hidden', q !== '' && r.textContent.toLowerCase().indexOf(q) < 0);
    });
  });
});
document.querySelectorAll('table.sortable th').forEach(function (th, k) {
  th.title = 'sort by this column';
  th.addEventListener('click', function () {
    var t = th.closest('table'), body = t.tBodies[0], col = th.cellIndex;
    var up = th.dataset.dir !== 'up'; th.dataset.dir = up ? 'up' : 'down';
    var rows = Array.prototype.slice.call(body.rows);
    var key = function (r) { var c = r.cells[col]; return c.dataset.v !== undefined ?
      parseFloat(c.dataset.v) : c.textContent; };
    rows.sort(function (a, b) { var x = key(a), y = key(b);
      var n = (typeof x === 'number' && typeof y === 'number') ? x - y :
        String(x).localeCompare(String(y));
      return up ? n : -n; });
    var limit = t.dataset.first ? parseInt(t.dataset.first, 10) : rows.length;
    rows.forEach(function (r, i) { r.classList.toggle('more', i >= limit); body.appendChild(r); });
  });
});
"""


def _figure(path: Path, alt: str, caption: str) -> str:
    """A figure in the page, inline (SVG), with its caption."""
    svg = path.read_text()
    svg = svg.replace("<svg ", f'<svg role="img" aria-label="{html.escape(alt)}" ', 1)
    return f"<figure>{svg}<figcaption>{html.escape(caption)}</figcaption></figure>"


def _replay(viewer: str | None, **params: Any) -> str | None:
    if viewer is None:
        return None
    parts = [f"{k}={quote(str(v), safe='')}" for k, v in params.items()
             if v is not None and v != ""]
    return f"{viewer}#{'&'.join(parts)}"


def _against_the_human(episodes: pd.DataFrame, reference: str, level: float) -> list[str]:
    """The section "against the human" of runs on recorded scenes (SPEC section 8): each
    policy's label agreement with the reference on the same scenes, per axis, and the
    closed-loop measures beside the human's own. Empty for runs without recorded scenes."""
    from tap_bench.bench.scores.agreement import agreement_with_reference, scene_summary

    if "route_progress" not in episodes.columns:
        return []
    scenes = episodes[episodes["route_progress"].notna()
                      | episodes.get("log_ade", pd.Series(dtype=float)).notna()]
    if scenes.empty:
        return []
    human = "the human" if reference == "log" else f"the reference policy {reference}"
    parts = ["<h2>Against the human</h2>",
             f'<p class="note">Recorded scenes: every policy drove the recorded ego of the '
             f"same WOMD scenarios from 1.0 s, {human} drove them as logged. Paired by scene: "
             "an episode is named by its scenario id, and each policy's is compared with "
             f"{human}'s on the same scene. Collisions count first where the ego was at "
             "fault (SPEC 8: not when stopped and hit, hit from behind, or entered by a "
             "pedestrian or cyclist while stopped), all collisions beside them; the "
             "regression gate's crash check on these scenes counts at-fault ones.</p>"]
    agree = agreement_with_reference(scenes, reference, level=level)
    pct = level_text(level)
    if len(agree):
        shown = agree.assign(
            agreement=[f"{a}/{n} = {_pct(sh)} [{_pct(lo)}, {_pct(hi)}]" if n else "–"
                       for a, n, sh, lo, hi in zip(agree["agree"], agree["pairs"],
                                                   agree["share"], agree["low"],
                                                   agree["high"], strict=True)])
        wide = shown.pivot_table(index=["env", "policy"], columns="axis", values="agreement",
                                 aggfunc="first").reset_index()
        wide.columns.name = None
        parts.append(html_table(
            wide, table_id="human-agreement",
            caption=f"Label agreement with {human}: scenes where the policy's ego label on "
            f"an axis equals the human's on the same scene, with its {pct} Wilson interval. "
            "sdl is lateral and longitudinal together; interaction the relations to others "
            "(SPEC 7)."))
    summary = scene_summary(scenes)
    # at-fault collisions, off-road and route progress first: the measures of recorded
    # scenes in their registry's order, then the others (all collisions among them)
    from tap_bench.bench.measures import SCENE_MEASURES

    ids = [c for c in ("env", "policy", "episodes") if c in summary.columns]
    scene = [m.name for m in SCENE_MEASURES if m.name in summary.columns]
    summary = summary[[*ids, *scene, *(c for c in summary.columns
                                        if c not in ids and c not in scene)]]
    for col in summary.columns:
        if col not in ("env", "policy", "episodes"):
            summary[col] = summary[col].round(3)
    parts.append(html_table(
        summary, table_id="human-measures",
        caption="Closed-loop measures on recorded scenes, mean over scenes, paired by scene: "
        "crashed_at_fault (share of scenes where the ego collided at fault), off_road "
        "(share: left the road edges), route_progress (share of the human's path "
        "covered, 0-1), crashed (all collisions), ran_red_light (share), log_ade and "
        f"log_fde (mean and final distance to the human's ego, m). The {reference} row "
        "is the floor: the human's own boxes can overlap others' in the log."))
    return parts


def write_report(folder: str | os.PathLike, summary: dict[str, Any], episodes: pd.DataFrame,
                 scores: Scores, *, viewer: str | None = None,
                 cache: EpisodeCache | None = None) -> Path:
    """Write ``plots/*.svg`` and ``report.html`` into a run folder; returns the HTML path.

    Args:
        folder: the run folder.
        summary: the run's ``summary.json`` content.
        episodes: the episode table.
        scores: the scored tables.
        viewer: the replay viewer's page relative to the report (``viewer/index.html``):
            rows naming episodes or labels link to their replay; None: no links.
        cache: the episode cache: the figures of unchanged scores are read from it
            (:func:`write_plots`).
    """
    folder = Path(folder)
    reference = str(summary.get("reference_policy", ""))
    suite = summary.get("suite", {})
    level = run_level(summary)
    pct = level_text(level)  # every interval of the run is at the suite's level
    plots = {p.stem: p for p in write_plots(scores, folder / "plots", reference=reference,
                                            level=level, cache=cache)}
    run = str(summary.get("run", ""))
    parts = [f"<h1>tap-bench run {html.escape(run)}</h1>",
             f"<p>Suite <b>{html.escape(str(suite.get('name', '')))}</b> "
             f"(v{suite.get('version', 0)}): {html.escape(str(suite.get('description', '')))}"
             "</p>"]
    if viewer:
        parts.append(f'<p><a href="{html.escape(viewer)}" target="_blank">▶ Open the replay '
                     "viewer</a>: every episode as a top-down animation with its labels, two "
                     "policies side by side on the same seed. The ▶ replay links below open "
                     "the episode a row is about.</p>")

    page = _Page(plots, reference, level, pct, viewer)
    parts.extend(_summary_section(page, summary, episodes, scores))
    parts.extend(_against_the_human(episodes, reference, level))
    from tap_bench.bench.report.agents import agents_report_section  # runs with seed groups only

    parts.extend(agents_report_section(folder, episodes, reference=reference, level=level,
                                       viewer=viewer))
    parts.extend(_env_section(page, summary, episodes, scores))
    parts.extend(_comparison_section(page, summary, episodes, scores))
    parts.extend(_coverage_section(page, summary, episodes, scores))
    parts.extend(_power_section(page, summary, episodes, scores))
    parts.extend(realism_section(summary.get("realism") or []))
    parts.extend(_run_section(page, summary, episodes, scores))
    text = ("<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<link rel=\"icon\" href=\"data:,\">"
            f"<title>tap-bench {html.escape(run)}</title>"
            f"<style>{_CSS}</style></head><body>{''.join(parts)}"
            f"<script>{_SCRIPT}</script></body></html>\n")
    path = folder / "report.html"
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


@dataclass(frozen=True)
class _Page:
    """What every section of the report reads: the figures written (name -> path), the
    reference policy, the intervals' level and its text (``95 %``), and the replay viewer's
    page (None: no replay links)."""

    plots: Mapping[str, Path]
    reference: str
    level: float
    pct: str
    viewer: str | None

    def img(self, name: str, alt: str, caption: str) -> str:
        """The figure ``name`` with its caption ("" when it was not drawn)."""
        return _figure(self.plots[name], alt, caption) if name in self.plots else ""


def _summary_section(page: _Page, summary: dict[str, Any], episodes: pd.DataFrame,
                     scores: Scores) -> list[str]:
    """The summary: episodes with one outcome, the verdict per policy, the trade-off figure, the
    summary table against the reference and how the intervals are computed."""
    reference = page.reference
    pct = page.pct
    img = page.img
    parts: list[str] = []
    pooled_env = "all" if len(_envs(scores)) > 1 else (_envs(scores) or ["–"])[0]
    one = summary.get("one_outcome_cells") or []
    if one:
        listed = ", ".join(f"{c['env']}/{c['policy']} ({c['n']})" for c in one)
        parts.append(f'<p class="note warning">One outcome on every seed: {html.escape(listed)}.'
                     " These episodes are not independent samples (the scene does not vary "
                     "with its seed for that policy); their intervals, pooled figures and "
                     "contexts count one episode as many.</p>")
    verdict = summary.get("verdict") or []
    if verdict:
        parts.append(f"<h2>Verdict: each policy against {html.escape(reference)}</h2>")
        parts.append('<p class="note">Paired by seed, safety first (crash rate, minimum TTC, '
                     "minimum headway), then efficiency, then behaviour; each claim with its "
                     f"{pct} interval (crash rate in percentage points). A policy that is less "
                     "safe is never called better, however fast. Per-env claims are not "
                     "corrected across envs; the regression gate is.</p>")
        by_policy: dict[str, list[dict[str, Any]]] = {}
        for row in verdict:
            by_policy.setdefault(str(row["policy"]), []).append(row)
        items = []
        for policy, rows in by_policy.items():
            lines = "".join(f"<li><b>{html.escape(str(r['area']))}</b>: "
                            f"{html.escape(str(r['word']))}"
                            + (f" <span class=\"note\">({html.escape(str(r['evidence']))})"
                               "</span>" if r.get("evidence") else "") + "</li>"
                            for r in rows)
            word = html.escape(str(rows[0].get("overall", "")))
            cls = ("worse" if word.startswith("less safe") else "better" if
                word.startswith("safer") else "same")
            items.append(f'<div class="verdict"><p><b>{html.escape(policy)}</b>: '
                         f'<span class="{cls}">{word}</span></p><ul>{lines}</ul></div>')
        parts.append("".join(items))
    parts.append(img("tradeoff", "safety rates against progress per env",
                     "Safety against progress, per env: each policy's safety rate (the "
                     f"measures of role safety that are rates, the crash rate built in; {pct} "
                     "Wilson interval) against its progress (role progress, the mean speed "
                     f"built in; {pct} t interval), a row of panels per pair; the reference "
                     "is the square. Down is safer, right is more progress."))
    parts.append("<h2>Summary: each policy against the reference</h2>")
    parts.append(html_table(
        summary_table(scores, reference), table_id="summary", max_rows=50,
        caption=f"Env: {pooled_env}. Each cell: the policy's mean over episodes, its {pct} "
        "interval in brackets, and its paired difference from the reference policy "
        f"{reference} on the same seeds: ▲ better or ▼ worse when the difference's {pct} "
        f"interval excludes 0, = no difference otherwise. {_measures_text(summary)}"
        "Coverage: share of the reference corpus's labels the policy shows; novel: share of "
        "episodes whose label the reference never shows; under each, the same-policy figure "
        "(the reference's episodes split in halves, one held against the other) and the "
        f"policy's difference from it at those sizes with its {pct} interval (a reference "
        "never shows everything its own policy does: read the difference, not the figure "
        "alone)."))
    if scores.methods:
        parts.append('<details><summary class="note">How the intervals are computed</summary>'
                     "<ul>" + "".join(f"<li><b>{html.escape(k)}</b>: {html.escape(v)}</li>"
                                      for k, v in scores.methods.items()) + "</ul></details>")

    return parts


def _env_section(page: _Page, summary: dict[str, Any], episodes: pd.DataFrame,
                 scores: Scores) -> list[str]:
    """Per env: the measures and labels figures, the crashed episodes, the pooled figure and
    the table of every measure."""
    reference = page.reference
    level = page.level
    pct = page.pct
    viewer = page.viewer
    img = page.img
    parts: list[str] = []
    parts.append("<h2>Per env</h2>")
    for env in _envs(scores):
        parts.append(f'<h3 id="env-{html.escape(_slug(env))}">{html.escape(env)}</h3>')
        parts.append(img(
            f"measures_{_slug(env)}", f"measures in {env}",
            f"Safety and efficiency in {env}: each policy's mean over its episodes (dot) and "
            f"{pct} interval (bar), one panel per measure; the dashed line is the reference "
            f"policy {reference}. Read across a panel: a bar that does not reach the dashed "
            "line differs from the reference. Scales are fitted to the values shown."))
        parts.append(img(
            f"labels_{_slug(env)}", f"label distribution in {env}",
            f"Behaviour in {env}: the share of each policy's episodes whose ego carries each "
            f"SDL label (rows, most frequent first, at most {TOP_LABELS}); darker is more "
            "frequent, the colour scale runs from 0 to the largest share shown."))
        crashed = episodes[(episodes["env"] == env) & (episodes["status"] == "ok")
                           & episodes["crashed"].fillna(False).astype(bool)]
        if len(crashed):
            # recorded scenes: each episode by its scenario id, with whom and whose fault
            real = [c for c in ("scenario_id", "crash_with", "crash_fault")
                    if "crash_fault" in crashed and crashed["crash_fault"].notna().any()
                    and c in crashed]
            parts.append(html_table(
                crashed[["policy", "seed", *real, "sdl"]].rename(columns={
                    "sdl": "ego label", "scenario_id": "scenario", "crash_with": "with",
                    "crash_fault": "fault"}),
                table_id=f"crashed-{_slug(env)}", text_columns=("ego label",),
                caption=f"Crashed episodes in {env}: the ego collided"
                + (" (recorded scenes: named by scenario id; with: the agent whose box "
                   "overlapped the ego's most; fault: SPEC 8's rule that decided)."
                   if real else "."),
                links=[_replay(viewer, ep=r.scenario_id, b=reference)
                       for r in crashed.itertuples()]))
    if "all" in set(scores.measures.get("env", [])):
        parts.append("<h3>All envs pooled</h3>")
        parts.append(img("measures_all", "measures pooled over envs",
                         "All envs pooled (each env resampled on its own, so each keeps its "
                         f"weight): means and {pct} intervals as above."))
    parts.append(html_table(_display_measures(scores.measures, level), table_id="measures",
                            caption="Every measure per env and policy: mean over episodes and "
                            f"{pct} interval, in the measure's unit."))

    return parts


def _comparison_section(page: _Page, summary: dict[str, Any], episodes: pd.DataFrame,
                        scores: Scores) -> list[str]:
    """The matched comparisons: paired by seed (labels, measures, probability of improvement,
    forest plots), by SDL label, and by interaction context."""
    plots = page.plots
    level = page.level
    pct = page.pct
    viewer = page.viewer
    img = page.img
    parts: list[str] = []
    parts.append("<h2>Matched comparison: paired by seed</h2>")
    parts.append('<p class="note">Each policy against the reference on the same initial '
                 "traffic (the same seed).</p>")
    parts.append(html_table(_display_paired(scores.paired, level), table_id="paired",
                            caption="Share of seeds on which A's and B's egos carry the same "
                            "label."))
    parts.append(img("improvement", "probability of improvement",
                     "Probability that A does better than B on the same seed (ties count one "
                     f"half), per measure, with {pct} intervals, all envs pooled. 0.5 is no "
                     "difference; right of it A is better."))
    parts.append(html_table(_display_paired_measures(scores.paired_measures, level),
                            table_id="paired_measures",
                            caption="Measures paired by seed: means of A and B, the mean "
                            f"paired difference A − B in the measure's unit with its {pct} "
                            "interval, and P(A better)."))
    for key in sorted(k for k in plots if k.startswith("forest_")):
        parts.append(img(key, f"forest plot {key}",
                         "Label frequencies paired by seed: for the labels that differ most, "
                         "the share of seeds on which A shows the label minus the share for "
                         f"B, in percentage points (dot, {pct} interval as a bar); the grey "
                         "band is the simultaneous band over all labels: a label whose band "
                         "excludes 0 differs even after looking at every label."))
    pl = scores.paired_labels
    parts.append(html_table(
        _display_paired_labels(pl, level), table_id="paired_labels", text_columns=("label",),
        caption="Every label's paired frequency difference (share of seeds, percentage "
        "points); replay opens an episode with the label (of A when A shows it, else of B) "
        "beside the other policy on the same seed.",
        links=[_replay(viewer, f_env=r.env if r.env != "all" else "",
                       # the policy that shows the label plays as A, the other beside it
                       f_policy=r.policy_a if r.freq_a > 0 else r.policy_b, f_sdl=r.label,
                       b=r.policy_b if r.freq_a > 0 else r.policy_a)
               for r in pl.itertuples()] if len(pl) else None))
    parts.append("<h2>Matched comparison: by SDL label</h2>")
    mt = scores.matched
    parts.append(html_table(
        _display_matched(mt, level), table_id="matched", text_columns=("label",),
        caption="Inside each group of episodes with the same ego label in one env (both "
        f"policies present): the measures of A and B compared (unpaired, {pct} intervals); "
        "replay opens the group's first episode of A.",
        links=[_replay(viewer, f_env=r.env, f_policy=r.policy_a, f_sdl=r.label,
                       b=r.policy_b) for r in mt.itertuples()] if len(mt) else None))
    if "interaction" in episodes.columns and episodes["interaction"].notna().any():
        ctx = (episodes[episodes["status"] == "ok"].dropna(subset=["interaction"])
               .groupby(["env", "policy", "interaction"]).size().rename("episodes")
               .reset_index().sort_values(["env", "episodes"], ascending=[True, False]))
        parts.append("<h2>Interaction contexts</h2>")
        parts.append(html_table(
            ctx, table_id="interactions", text_columns=("interaction",),
            caption="The ego's interaction labels (what it did around others) per env and "
            "policy, with the number of episodes; replay opens the first one.",
            links=[_replay(viewer, f_env=r.env, f_policy=r.policy, f_sdl=r.interaction)
                   for r in ctx.itertuples()]))
    parts.extend(_context_comparison(scores.contexts, pct))
    return parts


def _coverage_section(page: _Page, summary: dict[str, Any], episodes: pd.DataFrame,
                      scores: Scores) -> list[str]:
    """Coverage of the references, diversity, unique manoeuvres (novelty, novel labels) and the
    scenarios matched across data sets."""
    reference = page.reference
    level = page.level
    pct = page.pct
    viewer = page.viewer
    img = page.img
    parts: list[str] = []
    parts.append("<h2>Behaviour coverage</h2>")
    parts.append(img("coverage", "coverage",
                     "Coverage, all envs pooled: the share of the reference corpus's labels "
                     "each policy shows (left) and the same weighted by how often the "
                     f"reference shows each label (right), with {pct} intervals; one colour "
                     "per reference corpus."))
    parts.append(html_table(_display_coverage(scores.coverage, level), table_id="coverage",
                            caption="Coverage per env and reference, scored on whole "
                            "labels (episodes, or windows of a real corpus's track length) "
                            "and on the manoeuvres the episodes contain (segments: the labels "
                            "of their runs, which repeat where whole labels rarely do); "
                            "beside each, the same-policy figure (the reference split in "
                            "halves) and the policy's difference from it at those sizes with "
                            f"its {pct} interval; with the diversity of each policy's "
                            "labels."))
    if not scores.diversity.empty:
        parts.append("<h2>Behaviour diversity</h2>")
        parts.append(html_table(
            diversity_display(scores.diversity), table_id="diversity",
            caption="Hill numbers of each policy's ego labels (q0: distinct labels, q1: "
            "exp(Shannon entropy), q2: inverse Simpson) at a common number of episodes per "
            "env, with the sample completeness (the share of the policy's label distribution "
            "the episodes have shown); 'whole distribution' is the asymptotic estimate, "
            "'at least' where the completeness is too low to estimate it; 'all' is the mean "
            "over envs."))
    parts.append("<h2>Unique manoeuvres</h2>")
    parts.append(img("novelty", "novelty",
                     "Novelty rate, all envs pooled: the share of each policy's episodes "
                     f"whose ego label the reference corpus never shows, with {pct} "
                     "intervals; one colour per reference."))
    parts.append(html_table(_display_novelty(scores.novelty, level), table_id="novelty",
                            caption="Novelty per env and reference, on whole labels "
                            "and on segments (an episode is novel when one of its segments "
                            "carries a label the reference never shows), beside the "
                            "same-policy figure and the difference from it."))
    nl = scores.novel_labels
    parts.append(html_table(
        _display_novel_labels(nl), table_id="novel_labels", text_columns=("label", "example"),
        caption="Novel labels with an example episode, each (env, label) once (the pooled "
        "figures count these rows); for segments, the segment labels the reference never "
        "shows; replay opens the example beside the reference policy on the same seed.",
        links=[_replay(viewer, ep=r.example_scenario, b=reference)
               for r in nl.itertuples()] if len(nl) else None))
    if not scores.scenario_matches.empty:
        parts.append("<h2>Scenarios matched across data sets</h2>")
        parts.append(html_table(scores.scenario_matches, table_id="scenario_matches",
                                caption="Each simulated episode beside its nearest WOMD "
                                "scenarios by scenario-level SDL (Scenario2Vector distance)."))

    return parts


def _power_section(page: _Page, summary: dict[str, Any], episodes: pd.DataFrame,
                   scores: Scores) -> list[str]:
    """The regression gate's power at this run's seed count (empty: no power table)."""
    parts: list[str] = []
    if not scores.gate_power.empty:
        power = power_summary(scores.gate_power)
        parts.append("<h2>Regression gate: power at this seed count</h2>")
        parts.append(html_table(
            power, table_id="gate_power",
            caption="Per metric, the probability that 'bench check' on these seeds fails a "
            "cell whose metric worsened by 'effect' (the gate's 'detect' margins): the "
            "gate's own rule (margin and weighted one-sided test), exact for rates, "
            "simulated for means; median and weakest (env, policy), and the seeds the "
            f"weakest needs for {POWER:.0%}."))
        for r in power[power["cells_underpowered"] > 0].itertuples():
            parts.append(f'<p class="note">{html.escape(r.metric)}: {r.cells_underpowered} '
                         f"of {r.cells} (env, policy) cells catch a worsening of {r.effect:g} "
                         f"with less than {POWER:.0%} probability at {r.n} seeds; up to "
                         f"{r.seeds_for_power:.0f} seeds needed.</p>")

    return parts


def _run_section(page: _Page, summary: dict[str, Any], episodes: pd.DataFrame,
                 scores: Scores) -> list[str]:
    """The run: its facts (suite, seeds, level, thresholds, references, versions), the failed
    episodes and the timings."""
    reference = page.reference
    suite = summary.get("suite", {})
    parts: list[str] = []
    parts.append("<h2>The run</h2>")
    facts = pd.DataFrame([
        ("envs", ", ".join(e if isinstance(e, str) else str(e.get("name", "womd"))
                           for e in suite.get("envs", []))),
        ("policies", ", ".join(suite.get("policies", []))),
        ("seeds", _seed_text(summary.get("seeds", []))),
        ("SDL level", summary.get("level", "")),
        ("thresholds", _thresholds_text(summary.get("thresholds"))),
        ("reference policy", reference),
        ("references", "; ".join(
            f"{name}: " + (", ".join(Path(p).name for p in src) if isinstance(src, list)
                           else Path(str(src)).name)
            for name, src in summary.get("references", {}).items()) or "–"),
        ("episodes", f"{summary.get('n_episodes', len(episodes))} "
                     f"({summary.get('n_failed', 0)} failed)"),
        ("created", summary.get("created", "")),
        ("versions", ", ".join(f"{k} {v}" for k, v in summary.get("versions", {}).items())),
    ], columns=["what", "value"])
    parts.append(html_table(facts, table_id="facts", max_rows=50))
    failed = episodes[episodes["status"] != "ok"]
    parts.append("<h3>Failed episodes</h3>")
    parts.append(html_table(failed[["env", "policy", "seed", "error"]], table_id="failed",
                            caption="Left out of every score.")
                 if len(failed) else '<p class="note">none</p>')
    parts.append(timings_html(summary.get("timings", {})))
    return parts


def _context_comparison(contexts: pd.DataFrame, pct: str) -> list[str]:
    """The run's contexts table (:func:`tap_bench.bench.scores.contexts.context_scores`): each
    policy against the reference inside each interaction context, the measures with an
    interval first; nothing when no context was met by both."""
    if contexts is None or not len(contexts):
        return []
    from tap_bench.bench.scores.contexts import context_measures

    entries = {m.name: m for m in context_measures()}
    rows = []
    for r in contexts.itertuples():
        m = entries.get(r.measure)
        scale = m.scale if m is not None else 1.0
        unit = ("points" if m.is_rate else m.display_unit) if m is not None else r.unit
        diff = f"{scale * r.diff:+.2f} {unit}" if pd.notna(r.diff) else ""
        interval = (f"[{scale * r.diff_low:+.2f}, {scale * r.diff_high:+.2f}]"
                    if pd.notna(r.diff_low) and pd.notna(r.diff_high) else "")
        rows.append({"env": r.env, "context": r.context,
                     "policy": f"{r.policy_a} vs {r.policy_b}",
                     "measure": m.label if m is not None else r.measure,
                     "seeds paired": r.n_pairs, "episodes": f"{r.n_a} / {r.n_b}",
                     "difference": diff, "interval": interval, "method": r.method})
    table = pd.DataFrame(rows)
    table = table.assign(_no=table["interval"] == "").sort_values(
        ["_no", "env", "context", "policy"], kind="stable").drop(columns="_no")
    return [html_table(
        table, table_id="context-comparison",
        text_columns=("env", "context", "policy", "measure", "method"),
        caption="Each policy against the reference inside each interaction context (A - B; "
        f"{pct} intervals): paired by seed where both meet the context, else unpaired, as "
        "tap-bench contexts compares them (contexts.parquet).")]


def run_level(summary: dict[str, Any]) -> float:
    """The interval level of a run (its suite's ``bootstrap.level``; 0.95 for a run folder
    older than the field)."""
    bootstrap = (summary.get("suite") or {}).get("bootstrap") or {}
    return float(bootstrap.get("level", 0.95))


def _measures_text(summary: dict[str, Any]) -> str:
    """What the summary's measure cells mean, from the run's measure entries: rates in % of
    episodes, and the caps of capped measures."""
    entries = run_measures(summary)
    rates = [e["label"] for e in entries if e.get("kind") == "rate"]
    capped = [e for e in entries if e.get("kind") != "rate" and e.get("bounds")]
    out = ""
    if rates:
        out += f"{', '.join(rates).capitalize()} in % of episodes. "
    if capped:
        out += "Capped: " + ", ".join(f"{e['label']} at {e['bounds'][1]:g} {e['unit']}"
                                      for e in capped) + ". "
    return out
