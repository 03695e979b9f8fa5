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

import pandas as pd

from tap_bench.bench.gate.power import power_summary
from tap_bench.bench.measures import MEASURES, SCENE_MEASURES
from tap_bench.bench.report.figures import TOP_LABELS, draw_figures
from tap_bench.bench.report.pages import timings_html
from tap_bench.bench.report.realism import realism_section
from tap_bench.bench.report.tables import (
    _slug,
    diversity_display,
    html_table,
    human_of,
    level_text,
    page_tables,
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


def write_plots(scores: Scores, folder: str | os.PathLike, *,
                reference: str | None = None, level: float = 0.95,
                cache: EpisodeCache | None = None) -> list[Path]:
    """Write the SVG figures of a scored run into ``folder`` and return their paths
    (``level``: the run's interval level, for the legends).

    Per env: ``labels_<env>.svg`` (label heat map) and ``measures_<env>.svg``; pooled:
    ``measures_all.svg``, ``tradeoff.svg`` (crash rate against mean speed, per env),
    ``improvement.svg``, ``coverage.svg``, ``forest_<A>_vs_<B>.svg`` (a panel per env),
    ``novelty.svg``.

    The figures are drawn by :func:`tap_bench.bench.report.figures.draw_figures`; with a
    ``cache``, those of scores equal to an earlier run's (every table, value for value, the
    reference, the level, the registered measures' entries and the code) are read from it
    (:func:`tap_bench.bench.cache.memoised`): the same bytes.
    """
    from tap_bench.bench.cache import memoised, table_digest

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    # the figures draw every registered measure's label, unit, bounds and direction, which
    # the tables do not hold (a plug-in's measure can change them with the same values)
    inputs = None if cache is None else {
        "tables": {name: table_digest(t) for name, t in scores.tables().items()},
        "reference": reference or "", "level": level,
        "measures": [m.to_dict() for m in (*MEASURES, *SCENE_MEASURES)]}
    envs = scores.envs  # a label heat map and a measures plot each
    figures = memoised(cache, "plots", inputs,
                       lambda: draw_figures(scores, envs, reference or "", level), dict, dict)
    paths = []
    for name, data in figures.items():
        (folder / name).write_bytes(data)
        paths.append(folder / name)
    return paths


def write_report(folder: str | os.PathLike, summary: dict[str, Any], episodes: pd.DataFrame,
                 scores: Scores, *, viewer: str | None = None,
                 cache: EpisodeCache | None = None) -> Path:
    """Write ``plots/*.svg`` and ``report.html`` into a run folder; returns the HTML path.

    The page is made in steps: its figures drawn (:func:`write_plots`), the agents'
    section made (:mod:`~tap_bench.bench.report.agents`, runs with seed groups), the gate's
    power summed up per metric (:func:`~tap_bench.bench.gate.power.power_summary`), its
    tables made (:func:`~tap_bench.bench.report.tables.page_tables`), then each section's
    headings and text placed around them, top to bottom.

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
    plots = {p.stem: p for p in write_plots(scores, folder / "plots", reference=reference,
                                            level=level, cache=cache)}
    from tap_bench.bench.report.agents import agents_report_section  # runs with seed groups only

    agents = agents_report_section(folder, episodes, reference=reference, level=level,
                                   viewer=viewer)
    power = power_summary(scores.gate_power)  # the gate's power per metric
    page = _Page(plots, page_tables(summary, episodes, scores, power, reference=reference,
                                    level=level, viewer=viewer),
                 scores.envs, "all" in set(scores.measures.get("env", [])), reference,
                 human_of(reference), level_text(level),  # every interval at the suite's level
                 scores.methods)
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
    parts.extend(_summary_section(page, summary))
    parts.extend(_human_section(page))
    parts.extend(agents)
    parts.extend(_env_section(page))
    parts.extend(_comparison_section(page))
    parts.extend(_coverage_section(page))
    parts.extend(_power_section(page))
    parts.extend(realism_section(summary.get("realism") or []))
    parts.extend(_run_section(page, summary))
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
    """What every section of the report reads, made from the scores before the sections:
    the figures written (name -> path), the tables made (id -> HTML), the envs scored,
    whether the measures are pooled over them too (an ``"all"`` env), the reference
    policy, who drove the recorded scenes as logged, the intervals' level as text
    (``95 %``) and how each table's intervals were computed (table -> text)."""

    plots: Mapping[str, Path]
    tables: Mapping[str, str]
    envs: list[str]
    pooled: bool
    reference: str
    human: str
    pct: str
    methods: Mapping[str, str]

    def img(self, name: str, alt: str, caption: str) -> str:
        """The figure ``name`` with its caption ("" when it was not drawn)."""
        return _figure(self.plots[name], alt, caption) if name in self.plots else ""


def _summary_section(page: _Page, summary: dict[str, Any]) -> list[str]:
    """The summary: episodes with one outcome, the verdict per policy, the trade-off figure, the
    summary table against the reference and how the intervals are computed."""
    reference = page.reference
    pct = page.pct
    parts: list[str] = []
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
        parts.append(_verdict_html(verdict))
    parts.append(page.img("tradeoff", "safety rates against progress per env",
                          "Safety against progress, per env: each policy's safety rate (the "
                          f"measures of role safety that are rates, the crash rate built in; "
                          f"{pct} Wilson interval) against its progress (role progress, the "
                          f"mean speed built in; {pct} t interval), a row of panels per pair; "
                          "the reference is the square. Down is safer, right is more "
                          "progress."))
    parts.append("<h2>Summary: each policy against the reference</h2>")
    parts.append(page.tables["summary"])
    if page.methods:
        parts.append('<details><summary class="note">How the intervals are computed</summary>'
                     "<ul>" + "".join(f"<li><b>{html.escape(k)}</b>: {html.escape(v)}</li>"
                                      for k, v in page.methods.items()) + "</ul></details>")
    return parts


def _verdict_html(verdict: list[dict[str, Any]]) -> str:
    """The verdict's claims (``summary.json``'s ``verdict`` rows), a block per policy: its
    overall word, then each area's word with its evidence."""
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
    return "".join(items)


def _human_section(page: _Page) -> list[str]:
    """The section "against the human" of runs on recorded scenes (SPEC section 8): each
    policy's label agreement with the reference on the same scenes, per axis, and the
    closed-loop measures beside the human's own. Empty for runs without recorded scenes."""
    if "human-measures" not in page.tables:
        return []
    human = page.human
    return ["<h2>Against the human</h2>",
            f'<p class="note">Recorded scenes: every policy drove the recorded ego of the '
            f"same WOMD scenarios from 1.0 s, {human} drove them as logged. Paired by scene: "
            "an episode is named by its scenario id, and each policy's is compared with "
            f"{human}'s on the same scene. Collisions count first where the ego was at "
            "fault (SPEC 8: not when stopped and hit, hit from behind, or entered by a "
            "pedestrian or cyclist while stopped), all collisions beside them; the "
            "regression gate's crash check on these scenes counts at-fault ones.</p>",
            page.tables.get("human-agreement", ""), page.tables["human-measures"]]


def _env_section(page: _Page) -> list[str]:
    """Per env: the measures and labels figures, the crashed episodes, the pooled figure and
    the table of every measure."""
    reference = page.reference
    pct = page.pct
    img = page.img
    parts: list[str] = []
    parts.append("<h2>Per env</h2>")
    for env in page.envs:
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
        parts.append(page.tables.get(f"crashed-{_slug(env)}", ""))
    if page.pooled:
        parts.append("<h3>All envs pooled</h3>")
        parts.append(img("measures_all", "measures pooled over envs",
                         "All envs pooled (each env resampled on its own, so each keeps its "
                         f"weight): means and {pct} intervals as above."))
    parts.append(page.tables["measures"])
    return parts


def _comparison_section(page: _Page) -> list[str]:
    """The matched comparisons: paired by seed (labels, measures, probability of improvement,
    forest plots), by SDL label, and by interaction context."""
    tables = page.tables
    pct = page.pct
    img = page.img
    parts: list[str] = []
    parts.append("<h2>Matched comparison: paired by seed</h2>")
    parts.append('<p class="note">Each policy against the reference on the same initial '
                 "traffic (the same seed).</p>")
    parts.append(tables["paired"])
    parts.append(img("improvement", "probability of improvement",
                     "Probability that A does better than B on the same seed (ties count one "
                     f"half), per measure, with {pct} intervals, all envs pooled. 0.5 is no "
                     "difference; right of it A is better."))
    parts.append(tables["paired_measures"])
    for key in sorted(k for k in page.plots if k.startswith("forest_")):
        parts.append(img(key, f"forest plot {key}",
                         "Label frequencies paired by seed: for the labels that differ most, "
                         "the share of seeds on which A shows the label minus the share for "
                         f"B, in percentage points (dot, {pct} interval as a bar); the grey "
                         "band is the simultaneous band over all labels: a label whose band "
                         "excludes 0 differs even after looking at every label."))
    parts.append(tables["paired_labels"])
    parts.append("<h2>Matched comparison: by SDL label</h2>")
    parts.append(tables["matched"])
    if "interactions" in tables:
        parts.append("<h2>Interaction contexts</h2>")
        parts.append(tables["interactions"])
    if "context-comparison" in tables:
        parts.append(tables["context-comparison"])
    return parts


def _coverage_section(page: _Page) -> list[str]:
    """Coverage of the references, diversity, unique manoeuvres (novelty, novel labels) and the
    scenarios matched across data sets."""
    tables = page.tables
    pct = page.pct
    img = page.img
    parts: list[str] = []
    parts.append("<h2>Behaviour coverage</h2>")
    parts.append(img("coverage", "coverage",
                     "Coverage, all envs pooled: the share of the reference corpus's labels "
                     "each policy shows (left) and the same weighted by how often the "
                     f"reference shows each label (right), with {pct} intervals; one colour "
                     "per reference corpus."))
    parts.append(tables["coverage"])
    if "diversity" in tables:
        parts.append("<h2>Behaviour diversity</h2>")
        parts.append(tables["diversity"])
    parts.append("<h2>Unique manoeuvres</h2>")
    parts.append(img("novelty", "novelty",
                     "Novelty rate, all envs pooled: the share of each policy's episodes "
                     f"whose ego label the reference corpus never shows, with {pct} "
                     "intervals; one colour per reference."))
    parts.append(tables["novelty"])
    parts.append(tables["novel_labels"])
    if "scenario_matches" in tables:
        parts.append("<h2>Scenarios matched across data sets</h2>")
        parts.append(tables["scenario_matches"])
    return parts


def _power_section(page: _Page) -> list[str]:
    """The regression gate's power at this run's seed count (empty: no power table)."""
    if "gate_power" not in page.tables:
        return []
    return ["<h2>Regression gate: power at this seed count</h2>", page.tables["gate_power"]]


def _run_section(page: _Page, summary: dict[str, Any]) -> list[str]:
    """The run: its facts (suite, seeds, level, thresholds, references, versions), the failed
    episodes and the timings."""
    return ["<h2>The run</h2>", page.tables["facts"], "<h3>Failed episodes</h3>",
            page.tables["failed"], timings_html(summary.get("timings", {}))]


def run_level(summary: dict[str, Any]) -> float:
    """The interval level of a run (its suite's ``bootstrap.level``; 0.95 for a run folder
    older than the field)."""
    bootstrap = (summary.get("suite") or {}).get("bootstrap") or {}
    return float(bootstrap.get("level", 0.95))
