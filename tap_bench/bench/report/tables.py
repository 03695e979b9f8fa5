"""The run report's tables: numbers to their precision and unit, the summary of each policy
against the reference, the display forms of the scored tables, the escaped HTML table with
its "show all", search and sort, and every table of the page with its caption and replay
links (:func:`page_tables`, which :mod:`tap_bench.bench.report.page` places)."""

from __future__ import annotations

import html
from collections.abc import Sequence
from pathlib import Path
from typing import Any
from urllib.parse import quote

import numpy as np
import pandas as pd

from tap_bench.bench.gate.power import POWER
from tap_bench.bench.measures import MEASURES, SCENE_MEASURES, Measure, run_measures
from tap_bench.bench.scores.null import halves_text
from tap_bench.bench.scores.scoring import Scores

TABLE_ROWS = 10  # rows shown before "show all" in the HTML (the Parquet files hold all)


def level_text(level: float) -> str:
    """An interval's level as the report writes it: ``95 %``, ``80 %``, ``97.5 %``."""
    pct = float(level) * 100
    return f"{_num(pct, 0 if abs(pct - round(pct)) < 1e-9 else 1)} %"


def interval_heading(level: float) -> str:
    """The heading of an interval column at ``level``: ``95 % interval``."""
    return f"{level_text(level)} interval"


def _pooled(table: pd.DataFrame) -> pd.DataFrame:
    if table.empty or "env" not in table.columns:
        return table
    env = "all" if (table["env"] == "all").any() else sorted(table["env"].unique())[0]
    return table[table["env"] == env]


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in str(name))


# -- numbers --------------------------------------------------------------------------------

def _num(value: Any, decimals: int) -> str:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return "–"
    if not np.isfinite(v):
        return "–"
    text = f"{v:.{decimals}f}"
    return ("0" + (f".{'0' * decimals}" if decimals else "") if text.lstrip("-") ==
        f"{0:.{decimals}f}" else text)  # no "-0.00"


def _pct(value: Any, decimals: int = 0) -> str:
    try:
        return _num(float(value) * 100, decimals) + " %"
    except (TypeError, ValueError):
        return "–"


def _measure_value(m: Measure, value: Any) -> str:
    """A measure's value in its unit, to its entry's precision (a rate in whole %)."""
    if m.is_rate:
        return _pct(value)
    return f"{_num(value, m.decimals)} {m.display_unit}"


def _interval(lo: str, hi: str) -> str:
    return f"[{lo}, {hi}]" if lo != "–" or hi != "–" else ""


def _measure_interval(m: Measure, lo: Any, hi: Any) -> str:
    if m.is_rate:
        return _interval(_pct(lo), _pct(hi))
    return _interval(_num(lo, m.decimals), _num(hi, m.decimals))


def _mark(diff_low: Any, diff_high: Any, higher_is_better: bool) -> tuple[str, str]:
    """(symbol, class) of a paired difference: better, worse or no difference (the interval
    covers 0)."""
    lo, hi = float(diff_low), float(diff_high)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return "", ""
    if lo > 0 or hi < 0:
        up = lo > 0
        better = up == higher_is_better
        return ("▲ better", "better") if better else ("▼ worse", "worse")
    return ("= no difference", "same")

def html_table(table: pd.DataFrame, *, caption: str = "", max_rows: int = TABLE_ROWS,
               table_id: str = "", text_columns: Sequence[str] = (),
               links: Sequence[str | None] | None = None) -> str:
    """A table as escaped HTML: text columns left-aligned, the first ``max_rows`` rows shown
    and the rest behind a button, with a search box and sortable columns when long.

    Args:
        table: the cells: plain values (formatted with :func:`_cell_text`) or
            ``(text, attributes)`` pairs (``class``, ``v``: a numeric sort key).
        caption: what the table shows.
        max_rows: rows shown before "show all".
        table_id: the ``id`` of the table element.
        text_columns: columns to left-align (besides those holding strings).
        links: per row, a replay address for a last "replay" column (None: no link).
    """
    if table.empty:
        return '<p class="note">(nothing to show)</p>'
    cols = list(table.columns)
    text_cols = set(text_columns) | {c for c in cols
                                     if table[c].map(lambda v: isinstance(v, str)).all()}
    head = "".join(f'<th class="{"l" if c in text_cols else ""}">{html.escape(str(c))}</th>'
                   for c in cols)
    if links is not None:
        head += '<th class="l">replay</th>'
    long = len(table) > max_rows
    body = []
    for i, row in enumerate(table.itertuples(index=False)):
        cells = []
        for c, v in zip(cols, row, strict=True):
            text, attrs = (v if isinstance(v, tuple) and len(v) == 2 and isinstance(v[1], dict)
                else (_cell_text(v), {}))
            cls = " ".join(x for x in ("l" if c in text_cols else "", attrs.get("class", ""))
                           if x)
            sort = f' data-v="{attrs["v"]}"' if "v" in attrs else _sort_key(v)
            if "title" in attrs:  # what the cell means, on hover
                sort += f' title="{html.escape(attrs["title"])}"'
            cells.append(f'<td class="{cls}"{sort}>'
                         f'{html.escape(text).replace(chr(10), "<br>")}</td>')
        if links is not None:
            href = links[i]
            cells.append(f'<td class="l"><a class="replay" href="{html.escape(href)}" '
                         f'target="_blank">▶ replay</a></td>' if href else '<td class="l"></td>')
        more = ' class="more"' if i >= max_rows else ""
        body.append(f"<tr{more}>{''.join(cells)}</tr>")
    cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
    ident = f' id="{table_id}"' if table_id else ""
    classes = "sortable" + (" long" if long else "")
    first = f' data-first="{max_rows}"' if long else ""
    tools = ""
    if long:
        tools = (f'<div class="tools"><button class="more" type="button">show all {len(table)} '
                 'rows</button><input class="search" type="search" placeholder="search all '
                 f'{len(table)} rows"></div>')
    return (f'<div class="tablebox">{tools}<div class="scroll"><table{ident} class="{classes}"'
            f"{first}>{cap}<thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody>"
            "</table></div></div>")


def _sort_key(value: Any) -> str:
    if isinstance(value, bool | np.bool_):
        return f' data-v="{int(value)}"'
    if isinstance(value, int | float | np.integer | np.floating) and np.isfinite(value):
        return f' data-v="{float(value)!r}"'
    return ""


def _cell_text(value: Any) -> str:
    if isinstance(value, bool | np.bool_):
        return "yes" if value else "no"
    if isinstance(value, int | np.integer):
        return str(int(value))
    if isinstance(value, float | np.floating):
        if not np.isfinite(value):
            return "–"
        if float(value).is_integer() and abs(value) < 1e6:
            return str(int(value))
        return f"{value:.3g}" if abs(value) >= 1e-3 else "0"
    if value is None or value is pd.NA:
        return "–"
    return str(value)


# -- tables for people -----------------------------------------------------------------------

def summary_table(scores: Scores, reference: str) -> pd.DataFrame:
    """Each policy against the reference, pooled over envs: one row per policy, one column
    per measure (value and interval), and the paired difference from the reference with a
    better / worse / no-difference mark; then coverage of and novelty against each
    reference corpus with intervals.

    Returns:
        display cells (``(text, attributes)`` pairs), the reference policy first.
    """
    m = _pooled(scores.measures)
    pm = _pooled(scores.paired_measures)
    cov = _pooled(scores.coverage)
    nov = _pooled(scores.novelty)
    policies = sorted(m["policy"].unique()) if len(m) else []
    policies = [p for p in policies if p == reference] + [p for p in policies if p != reference]
    rows = []
    for policy in policies:
        row: dict[str, Any] = {"policy": (policy + ("\n(reference)" if policy == reference
                                                     else ""), {"class": "l nowrap"})}
        for meas in MEASURES:
            name = meas.label
            r = m[(m["policy"] == policy) & (m["measure"] == meas.name)]
            if r.empty:
                row[name] = ("–", {})
                continue
            r = r.iloc[0]
            text = (f"{_measure_value(meas, r['mean'])}\n"
                    f"{_measure_interval(meas, r['low'], r['high'])}")
            cls = ""
            if policy == reference:
                cls = "ref"
            elif len(pm):
                d = pm[(pm["policy_a"] == policy) & (pm["policy_b"] == reference)
                       & (pm["measure"] == meas.name)]
                if len(d):
                    mark, cls = _mark(d["diff_low"].iloc[0], d["diff_high"].iloc[0],
                                      meas.higher_is_better)
                    text += f"\n{mark}"
            row[name] = (text, {"class": cls, "v": float(r["mean"]) if np.isfinite(r["mean"])
                                else "NaN"})
        for table, what, est, lo, hi in ((cov, "coverage of", "coverage", "coverage_low",
                                          "coverage_high"),
                                         (nov, "novel vs", "novel_rate", "novel_low",
                                          "novel_high")):
            for ref in sorted(table["reference"].unique()) if len(table) else []:
                c = table[(table["policy"] == policy) & (table["reference"] == ref)]
                if "unit" in c.columns:  # whole labels here; segments in the detail tables
                    c = c[~c["unit"].astype(str).str.endswith("segments")]
                if c.empty:
                    row[f"{what} {ref}"] = ("–", {})
                    continue
                c = c.iloc[0]
                text = f"{_pct(c[est])}\n{_interval(_pct(c[lo]), _pct(c[hi]))}"
                diff = "coverage_diff" if est == "coverage" else "novel_diff"
                if np.isfinite(c.get(diff, np.nan)):  # beside the same-policy figure
                    null = "null_coverage" if est == "coverage" else "null_novel_rate"
                    half = "half_coverage" if est == "coverage" else "half_novel_rate"
                    text += "\n" + halves_text(c[half], c[null], c[diff], c[diff + "_low"],
                                               c[diff + "_high"], percent=" %")
                row[f"{what} {ref}"] = (text, {"v": float(c[est])})
        gap = scores.gap
        for ref in sorted(gap["reference"].unique()) if len(gap) else []:
            g = gap[(gap["policy"] == policy) & (gap["reference"] == ref)]
            if g.empty:
                row[f"gap to {ref}"] = ("–", {})
                continue
            g = g.iloc[0]
            row[f"gap to {ref}"] = (
                f"{g['gap']:.2f}\n{_interval(f'{g.gap_low:.2f}', f'{g.gap_high:.2f}')}\n"
                f"floor {g['floor']:.2f}",
                {"v": float(g["gap"]), "title": "sim-to-real behaviour gap: total variation "
                 "distance of label shares from the reference's vehicles at the policy's "
                 "speeds (0 = drives like people, 1 = nothing in common); the floor is the "
                 "gap two samples of the reference show by chance"})
        rows.append(row)
    return pd.DataFrame(rows)


def _display_measures(table: pd.DataFrame, level: float) -> pd.DataFrame:
    rows = []
    for r in table.itertuples(index=False):
        meas = MEASURES.get(r.measure)
        if meas is None:
            continue
        rows.append({"env": r.env, "policy": r.policy,
                     "measure": meas.label,
                     "n": r.n, "mean": (_measure_value(meas, r.mean), {"v": r.mean}),
                     interval_heading(level): _measure_interval(meas, r.low, r.high)})
    return pd.DataFrame(rows)


def _display_paired_measures(table: pd.DataFrame, level: float) -> pd.DataFrame:
    rows = []
    for r in table.itertuples(index=False):
        meas = MEASURES.get(r.measure)
        if meas is None:
            continue
        mark, cls = _mark(r.diff_low, r.diff_high, meas.higher_is_better)
        rows.append({"env": r.env, "A": r.policy_a, "B": r.policy_b,
                     "measure": meas.label,
                     "pairs": r.n, "mean A": _measure_value(meas, r.mean_a),
                     "mean B": _measure_value(meas, r.mean_b),
                     "A − B": (_measure_value(meas, r.diff), {"v": r.diff}),
                     interval_heading(level): _measure_interval(meas, r.diff_low, r.diff_high),
                     "A vs B": (mark, {"class": cls}),
                     "P(A better)": (f"{_num(r.p_improvement, 2)} "
                                     f"{_interval(_num(r.p_low, 2), _num(r.p_high, 2))}",
                                     {"v": r.p_improvement})})
    return pd.DataFrame(rows)


def _display_paired(table: pd.DataFrame, level: float) -> pd.DataFrame:
    return pd.DataFrame([{
        "env": r.env, "A": r.policy_a, "B": r.policy_b, "pairs": r.n_pairs,
        "dropped": r.n_dropped, "same label": (_pct(r.agreement), {"v": r.agreement}),
        interval_heading(level): _interval(_pct(r.agreement_low), _pct(r.agreement_high))}
        for r in table.itertuples(index=False)])


def _display_paired_labels(table: pd.DataFrame, level: float) -> pd.DataFrame:
    rows = []
    for r in table.itertuples(index=False):
        mark, cls = _mark(r.diff_low, r.diff_high, True)
        mark = {"better": "▲ A more often", "worse": "▼ A less often"}.get(cls, mark)
        rows.append({"env": r.env, "A": r.policy_a, "B": r.policy_b, "label": r.label,
                     "share A": _pct(r.freq_a), "share B": _pct(r.freq_b),
                     "A − B [pp]": (_num(r.diff * 100, 1), {"v": r.diff}),
                     interval_heading(level): _interval(_num(r.diff_low * 100, 1),
                                                _num(r.diff_high * 100, 1)),
                     "band": _interval(_num(r.band_low * 100, 1), _num(r.band_high * 100, 1)),
                     "": (mark, {"class": cls})})
    return pd.DataFrame(rows)


def _display_matched(table: pd.DataFrame, level: float) -> pd.DataFrame:
    rows = []
    for r in table.itertuples(index=False):
        meas = MEASURES.get(r.measure)
        if meas is None:  # a group too small to test: listed with its sizes
            if getattr(r, "note", ""):
                rows.append({"env": r.env, "label": r.label, "A": r.policy_a,
                             "B": r.policy_b, "episodes A": r.n_a, "episodes B": r.n_b,
                             "measure": "–", "A vs B": r.note})
            continue
        mark, cls = _mark(r.diff_low, r.diff_high, meas.higher_is_better)
        rows.append({"env": r.env, "label": r.label, "A": r.policy_a, "B": r.policy_b,
                     "episodes A": r.n_a, "episodes B": r.n_b,
                     "measure": meas.label,
                     "mean A": _measure_value(meas, r.mean_a),
                     "mean B": _measure_value(meas, r.mean_b),
                     "A − B": (_measure_value(meas, r.diff), {"v": r.diff}),
                     interval_heading(level): _measure_interval(meas, r.diff_low, r.diff_high),
                     "A vs B": (mark, {"class": cls})})
    return pd.DataFrame(rows)


_NULL_COLUMNS = ("null_m", "null_paired", "half_coverage", "null_coverage", "coverage_diff",
                 "coverage_diff_low", "coverage_diff_high", "half_novel_rate",
                 "null_novel_rate", "novel_diff", "novel_diff_low", "novel_diff_high")


def _null_cells(r: dict, half: str, null: str, diff: str) -> dict:
    """The same-policy figure and the difference from it, as display cells."""
    if not np.isfinite(r.get(null, np.nan)):
        return {"same policy (halves)": "–", "difference at halves": "–"}
    return {"same policy (halves)": (f"{_pct(r[null])} (policy {_pct(r[half])}, halves of "
                                     f"{int(r['null_m'])})", {"v": r[null]}),
            "difference at halves": (f"{100 * r[diff]:+.1f} pts [{100 * r[diff + '_low']:+.1f},"
                                     f" {100 * r[diff + '_high']:+.1f}]", {"v": r[diff]})}


def _display_coverage(table: pd.DataFrame, level: float) -> pd.DataFrame:
    rows = []
    for r in table.to_dict("records"):
        row = {"env": r["env"], "policy": r["policy"], "reference": r["reference"],
               "scored on": r.get("unit", "episodes"), "episodes": r["n"],
               "coverage": (_pct(r["coverage"]), {"v": r["coverage"]}),
               interval_heading(level): _interval(_pct(r["coverage_low"]),
                                                  _pct(r["coverage_high"])),
               **_null_cells(r, "half_coverage", "null_coverage", "coverage_diff"),
               "weighted": (_pct(r["weighted_coverage"]), {"v": r["weighted_coverage"]}),
               "weighted interval": _interval(_pct(r["weighted_low"]), _pct(r["weighted_high"])),
               "distinct labels": r.get("n_distinct")}
        for key in r:  # diversity figures as the scoring gives them (bits, Hill numbers ...)
            if key not in row and key not in ("n", "coverage_low", "coverage_high",
                                              "weighted_coverage", "weighted_low",
                                              "weighted_high", "n_distinct", "coverage",
                                              "unit", *_NULL_COLUMNS):
                row[key] = (_num(r[key], 2), {"v": r[key]}) if isinstance(
                    r[key], float | np.floating) else r[key]
        rows.append(row)
    return pd.DataFrame(rows)


def _display_novelty(table: pd.DataFrame, level: float) -> pd.DataFrame:
    return pd.DataFrame([{
        "env": r["env"], "policy": r["policy"], "reference": r["reference"],
        "scored on": r.get("unit", "episodes"), "episodes": r["n"],
        "novel episodes": r["n_novel"],
        "novelty rate": (_pct(r["novel_rate"]), {"v": r["novel_rate"]}),
        interval_heading(level): _interval(_pct(r["novel_low"]), _pct(r["novel_high"])),
        **_null_cells(r, "half_novel_rate", "null_novel_rate", "novel_diff"),
        "novel labels": r["n_novel_labels"], "reference size": r["reference_size"]}
        for r in table.to_dict("records")])


def _display_novel_labels(table: pd.DataFrame) -> pd.DataFrame:
    return pd.DataFrame([{
        "env": r["env"], "policy": r["policy"], "reference": r["reference"],
        "scored on": r.get("unit", "episodes"), "label": r["label"],
        "episodes": r["count"], "share": (_pct(r["share"], 1), {"v": r["share"]}),
        "example": r["example_scenario"]} for r in table.to_dict("records")])


def _hill_text(est: float, low: float, high: float, bound: bool) -> str:
    if not np.isfinite(est):
        return "–"
    if bound:
        return f"at least {est:.1f}"
    return f"{est:.1f} [{low:.1f}, {high:.1f}]"


def diversity_display(table: pd.DataFrame) -> pd.DataFrame:
    """The diversity table as text, "at least" where a value is only a lower bound."""
    if table.empty:
        return table
    rows = []
    for r in table.to_dict("records"):
        row = {"env": r["env"], "policy": r["policy"], "episodes": r["n"],
               "at episodes": r["size"], "method": r["method"]}
        for q in (0, 1, 2):
            row[f"q{q}"] = _hill_text(r[f"hill_q{q}"], r[f"hill_q{q}_low"],
                                      r[f"hill_q{q}_high"], r["hill_is_bound"])
        if r.get("hill_order_broken", False):  # estimates rising with q: intervals widened
            row["q2"] += " (out of order: intervals widened)"
        row["completeness"] = (f"{r['completeness']:.0%} [{r['completeness_low']:.0%}, "
                               f"{r['completeness_high']:.0%}]")
        asym = ", ".join("–" if not np.isfinite(r[f"asymptote_q{q}"]) else
                         f"{r[f'asymptote_q{q}']:.1f}" for q in (0, 1, 2))
        if r.get("asymptote_order_broken", False):
            asym += " (out of order: not reported)"
        row["whole distribution (q0, q1, q2)"] = (f"at least {asym}" if r["asymptote_is_bound"]
                                                  else asym)
        rows.append(row)
    return pd.DataFrame(rows)


def _seed_text(seeds: list[int] | str) -> str:
    if seeds == "all":
        return "all (every scenario of the recorded scenes)"
    if not seeds:
        return ""
    if seeds == list(range(seeds[0], seeds[0] + len(seeds))):
        return f"{seeds[0]}-{seeds[-1]} ({len(seeds)})"
    return ", ".join(map(str, seeds))


def _thresholds_text(th: Any) -> str:
    if isinstance(th, dict) and isinstance(th.get("thresholds"), dict):
        units = th.get("units", {})
        return "; ".join(
            f"{dist} ({units.get(dist, '')}): " + ", ".join(f"{k} {v:g}" for k, v in vals.items())
            for dist, vals in th["thresholds"].items())
    return str(th)


# -- the page's tables -----------------------------------------------------------------------

def page_tables(summary: dict[str, Any], episodes: pd.DataFrame, scores: Scores,
                power: pd.DataFrame, *, reference: str, level: float, viewer: str | None
                ) -> dict[str, str]:
    """Every table of the report page as escaped HTML with its caption (:func:`html_table`),
    by the id the page places it under. A table the run has nothing for is left out: the
    recorded scenes' tables, the interaction contexts, diversity, the scenario matches and
    the gate's power.

    Args:
        summary: the run's ``summary.json`` content.
        episodes: the episode table.
        scores: the scored tables.
        power: the gate's power per metric (:func:`~tap_bench.bench.gate.power.
            power_summary` of ``scores.gate_power``; empty without a power table).
        reference: the reference policy.
        level: the intervals' level (0.95).
        viewer: the replay viewer's page relative to the report (``viewer/index.html``):
            rows that name episodes or labels link to their replay; None: no links.
    """
    pct = level_text(level)
    return {**_human_tables(episodes, reference, level),
            **_summary_tables(summary, scores, reference, pct),
            **_env_tables(episodes, scores, reference, level, pct, viewer),
            **_comparison_tables(episodes, scores, level, pct, viewer),
            **_coverage_tables(scores, reference, level, pct, viewer),
            **_power_tables(power),
            **_run_tables(summary, episodes, reference)}


def _replay(viewer: str | None, **params: Any) -> str | None:
    """The replay viewer's address showing what ``params`` name (None: no viewer)."""
    if viewer is None:
        return None
    parts = [f"{k}={quote(str(v), safe='')}" for k, v in params.items()
             if v is not None and v != ""]
    return f"{viewer}#{'&'.join(parts)}"


def human_of(reference: str) -> str:
    """Who drove the recorded scenes as logged, as the page names it."""
    return "the human" if reference == "log" else f"the reference policy {reference}"


def _human_tables(episodes: pd.DataFrame, reference: str, level: float) -> dict[str, str]:
    """Runs on recorded scenes (SPEC section 8): each policy's label agreement with the
    reference on the same scenes, per axis (``human-agreement``), and the closed-loop
    measures beside the human's own (``human-measures``); none for runs without recorded
    scenes."""
    from tap_bench.bench.scores.agreement import agreement_with_reference, scene_summary

    if "route_progress" not in episodes.columns:
        return {}
    scenes = episodes[episodes["route_progress"].notna()
                      | episodes.get("log_ade", pd.Series(dtype=float)).notna()]
    if scenes.empty:
        return {}
    human = human_of(reference)
    tables = {}
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
        tables["human-agreement"] = html_table(
            wide, table_id="human-agreement",
            caption=f"Label agreement with {human}: scenes where the policy's ego label on "
            f"an axis equals the human's on the same scene, with its {pct} Wilson interval. "
            "sdl is lateral and longitudinal together; interaction the relations to others "
            "(SPEC 7).")
    summary = scene_summary(scenes)
    # at-fault collisions, off-road and route progress first: the measures of recorded
    # scenes in their registry's order, then the others (all collisions among them)
    ids = [c for c in ("env", "policy", "episodes") if c in summary.columns]
    scene = [m.name for m in SCENE_MEASURES if m.name in summary.columns]
    summary = summary[[*ids, *scene, *(c for c in summary.columns
                                        if c not in ids and c not in scene)]]
    for col in summary.columns:
        if col not in ("env", "policy", "episodes"):
            summary[col] = summary[col].round(3)
    tables["human-measures"] = html_table(
        summary, table_id="human-measures",
        caption="Closed-loop measures on recorded scenes, mean over scenes, paired by scene: "
        "crashed_at_fault (share of scenes where the ego collided at fault), off_road "
        "(share: left the road edges), route_progress (share of the human's path "
        "covered, 0-1), crashed (all collisions), ran_red_light (share), log_ade and "
        f"log_fde (mean and final distance to the human's ego, m). The {reference} row "
        "is the floor: the human's own boxes can overlap others' in the log.")
    return tables


def _summary_tables(summary: dict[str, Any], scores: Scores, reference: str, pct: str
                    ) -> dict[str, str]:
    """The summary table: each policy against the reference (:func:`summary_table`)."""
    envs = scores.envs
    pooled_env = "all" if len(envs) > 1 else (envs or ["–"])[0]
    return {"summary": html_table(
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
        "alone).")}


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


def _env_tables(episodes: pd.DataFrame, scores: Scores, reference: str, level: float,
                pct: str, viewer: str | None) -> dict[str, str]:
    """Per env, its crashed episodes (``crashed-<env>``, where any crashed); every measure per
    env and policy (``measures``)."""
    tables = {}
    for env in scores.envs:
        crashed = episodes[(episodes["env"] == env) & (episodes["status"] == "ok")
                           & episodes["crashed"].fillna(False).astype(bool)]
        if len(crashed):
            # recorded scenes: each episode by its scenario id, with whom and whose fault
            real = [c for c in ("scenario_id", "crash_with", "crash_fault")
                    if "crash_fault" in crashed and crashed["crash_fault"].notna().any()
                    and c in crashed]
            tables[f"crashed-{_slug(env)}"] = html_table(
                crashed[["policy", "seed", *real, "sdl"]].rename(columns={
                    "sdl": "ego label", "scenario_id": "scenario", "crash_with": "with",
                    "crash_fault": "fault"}),
                table_id=f"crashed-{_slug(env)}", text_columns=("ego label",),
                caption=f"Crashed episodes in {env}: the ego collided"
                + (" (recorded scenes: named by scenario id; with: the agent whose box "
                   "overlapped the ego's most; fault: SPEC 8's rule that decided)."
                   if real else "."),
                links=[_replay(viewer, ep=r.scenario_id, b=reference)
                       for r in crashed.itertuples()])
    tables["measures"] = html_table(_display_measures(scores.measures, level),
                                    table_id="measures",
                                    caption="Every measure per env and policy: mean over "
                                    f"episodes and {pct} interval, in the measure's unit.")
    return tables


def _comparison_tables(episodes: pd.DataFrame, scores: Scores, level: float, pct: str,
                       viewer: str | None) -> dict[str, str]:
    """The matched comparisons: paired by seed (``paired``, ``paired_measures``,
    ``paired_labels``), by SDL label (``matched``), the interaction contexts met
    (``interactions``) and each policy against the reference inside them
    (``context-comparison``)."""
    pl, mt = scores.paired_labels, scores.matched
    tables = {
        "paired": html_table(_display_paired(scores.paired, level), table_id="paired",
                             caption="Share of seeds on which A's and B's egos carry the "
                             "same label."),
        "paired_measures": html_table(
            _display_paired_measures(scores.paired_measures, level),
            table_id="paired_measures",
            caption="Measures paired by seed: means of A and B, the mean paired difference "
            f"A − B in the measure's unit with its {pct} interval, and P(A better)."),
        "paired_labels": html_table(
            _display_paired_labels(pl, level), table_id="paired_labels",
            text_columns=("label",),
            caption="Every label's paired frequency difference (share of seeds, percentage "
            "points); replay opens an episode with the label (of A when A shows it, else of "
            "B) beside the other policy on the same seed.",
            links=[_replay(viewer, f_env=r.env if r.env != "all" else "",
                           # the policy that shows the label plays as A, the other beside it
                           f_policy=r.policy_a if r.freq_a > 0 else r.policy_b,
                           f_sdl=r.label, b=r.policy_b if r.freq_a > 0 else r.policy_a)
                   for r in pl.itertuples()] if len(pl) else None),
        "matched": html_table(
            _display_matched(mt, level), table_id="matched", text_columns=("label",),
            caption="Inside each group of episodes with the same ego label in one env (both "
            f"policies present): the measures of A and B compared (unpaired, {pct} "
            "intervals); replay opens the group's first episode of A.",
            links=[_replay(viewer, f_env=r.env, f_policy=r.policy_a, f_sdl=r.label,
                           b=r.policy_b) for r in mt.itertuples()] if len(mt) else None)}
    if "interaction" in episodes.columns and episodes["interaction"].notna().any():
        ctx = (episodes[episodes["status"] == "ok"].dropna(subset=["interaction"])
               .groupby(["env", "policy", "interaction"]).size().rename("episodes")
               .reset_index().sort_values(["env", "episodes"], ascending=[True, False]))
        tables["interactions"] = html_table(
            ctx, table_id="interactions", text_columns=("interaction",),
            caption="The ego's interaction labels (what it did around others) per env and "
            "policy, with the number of episodes; replay opens the first one.",
            links=[_replay(viewer, f_env=r.env, f_policy=r.policy, f_sdl=r.interaction)
                   for r in ctx.itertuples()])
    if scores.contexts is not None and len(scores.contexts):
        tables["context-comparison"] = _context_table(scores.contexts, pct)
    return tables


def _context_table(contexts: pd.DataFrame, pct: str) -> str:
    """The run's contexts table (:func:`tap_bench.bench.scores.contexts.context_scores`): each
    policy against the reference inside each interaction context, the measures with an
    interval first."""
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
    return html_table(
        table, table_id="context-comparison",
        text_columns=("env", "context", "policy", "measure", "method"),
        caption="Each policy against the reference inside each interaction context (A - B; "
        f"{pct} intervals): paired by seed where both meet the context, else unpaired, as "
        "tap-bench contexts compares them (contexts.parquet).")


def _coverage_tables(scores: Scores, reference: str, level: float, pct: str,
                     viewer: str | None) -> dict[str, str]:
    """Coverage of the references (``coverage``), diversity (``diversity``), novelty
    (``novelty``, ``novel_labels``) and the scenarios matched across data sets
    (``scenario_matches``)."""
    nl = scores.novel_labels
    tables = {"coverage": html_table(
        _display_coverage(scores.coverage, level), table_id="coverage",
        caption="Coverage per env and reference, scored on whole labels (episodes, or windows "
        "of a real corpus's track length) and on the manoeuvres the episodes contain "
        "(segments: the labels of their runs, which repeat where whole labels rarely do); "
        "beside each, the same-policy figure (the reference split in halves) and the "
        f"policy's difference from it at those sizes with its {pct} interval; with the "
        "diversity of each policy's labels.")}
    if not scores.diversity.empty:
        tables["diversity"] = html_table(
            diversity_display(scores.diversity), table_id="diversity",
            caption="Hill numbers of each policy's ego labels (q0: distinct labels, q1: "
            "exp(Shannon entropy), q2: inverse Simpson) at a common number of episodes per "
            "env, with the sample completeness (the share of the policy's label distribution "
            "the episodes have shown); 'whole distribution' is the asymptotic estimate, "
            "'at least' where the completeness is too low to estimate it; 'all' is the mean "
            "over envs.")
    tables["novelty"] = html_table(
        _display_novelty(scores.novelty, level), table_id="novelty",
        caption="Novelty per env and reference, on whole labels and on segments (an episode "
        "is novel when one of its segments carries a label the reference never shows), "
        "beside the same-policy figure and the difference from it.")
    tables["novel_labels"] = html_table(
        _display_novel_labels(nl), table_id="novel_labels", text_columns=("label", "example"),
        caption="Novel labels with an example episode, each (env, label) once (the pooled "
        "figures count these rows); for segments, the segment labels the reference never "
        "shows; replay opens the example beside the reference policy on the same seed.",
        links=[_replay(viewer, ep=r.example_scenario, b=reference)
               for r in nl.itertuples()] if len(nl) else None)
    if not scores.scenario_matches.empty:
        tables["scenario_matches"] = html_table(
            scores.scenario_matches, table_id="scenario_matches",
            caption="Each simulated episode beside its nearest WOMD scenarios by "
            "scenario-level SDL (Scenario2Vector distance).")
    return tables


def _power_tables(power: pd.DataFrame) -> dict[str, str]:
    """The regression gate's power at the run's seed count per metric (``power``:
    :func:`~tap_bench.bench.gate.power.power_summary`), with a note per metric that some
    cells catch with less than :data:`~tap_bench.bench.gate.power.POWER` probability; none
    without a power table."""
    if power.empty:
        return {}
    parts = [html_table(
        power, table_id="gate_power",
        caption="Per metric, the probability that 'bench check' on these seeds fails a "
        "cell whose metric worsened by 'effect' (the gate's 'detect' margins): the "
        "gate's own rule (margin and weighted one-sided test), exact for rates, "
        "simulated for means; median and weakest (env, policy), and the seeds the "
        f"weakest needs for {POWER:.0%}.")]
    for r in power[power["cells_underpowered"] > 0].itertuples():
        parts.append(f'<p class="note">{html.escape(r.metric)}: {r.cells_underpowered} '
                     f"of {r.cells} (env, policy) cells catch a worsening of {r.effect:g} "
                     f"with less than {POWER:.0%} probability at {r.n} seeds; up to "
                     f"{r.seeds_for_power:.0f} seeds needed.</p>")
    return {"gate_power": "".join(parts)}


def _run_tables(summary: dict[str, Any], episodes: pd.DataFrame, reference: str
                ) -> dict[str, str]:
    """The run's facts (``facts``: suite, seeds, level, thresholds, references, versions)
    and its failed episodes (``failed``; a note when none failed)."""
    suite = summary.get("suite", {})
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
    failed = episodes[episodes["status"] != "ok"]
    return {"facts": html_table(facts, table_id="facts", max_rows=50),
            "failed": html_table(failed[["env", "policy", "seed", "error"]], table_id="failed",
                                 caption="Left out of every score.")
            if len(failed) else '<p class="note">none</p>'}
