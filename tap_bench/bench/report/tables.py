"""The run report's tables: numbers to their precision and unit, the summary of each policy
against the reference, the display forms of the scored tables, and the escaped HTML table
with its "show all", search and sort (part of :mod:`tap_bench.bench.report.page`)."""

from __future__ import annotations

import html
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from tap_bench.bench.measures import MEASURES, Measure
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


def _envs(scores: Scores) -> list[str]:
    envs = set()
    for table in (scores.measures, scores.label_counts):
        if len(table) and "env" in table.columns:
            envs |= set(map(str, table["env"].unique()))
    envs.discard("all")
    return sorted(envs)


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
