"""The run report: PNG plots and one static HTML page (no server, nothing from the network).

:func:`write_report` writes ``plots/*.png`` and ``report.html`` into a run folder. The page
embeds its images as data URIs, so the HTML file alone is the whole report (mail it, open
it from disk); the PNG files are there for papers and slides. A small inline script sorts
and searches the long tables; without it the page still reads in full.

The page reads from the top: a summary table of each policy against the reference policy
(every measure with its interval and a better / worse / no-difference mark), then one panel
per env, then the comparisons, coverage and unique manoeuvres in detail. Every figure is
drawn at the size it is shown (text at least 10 px), its scales fitted to the data, its
labels whole; every table gives units and numbers to their precision, shows its first rows
and keeps the rest a click away. When the run has a replay viewer (``viewer/``), the rows
that name episodes or labels link to the replay that shows them.
"""

from __future__ import annotations

import base64
import html
import os
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import Any
from urllib.parse import quote

import numpy as np
import pandas as pd

from tap_bench.bench.measures import MEASURES, Measure
from tap_bench.bench.power import POWER, power_summary
from tap_bench.bench.scoring import Scores
from tap_bench.tableio import atomic_path

__all__ = ["diversity_display", "html_table", "summary_table", "write_plots", "write_report"]

TOP_LABELS = 12  # labels shown per heat map and forest plot
TABLE_ROWS = 10  # rows shown before "show all" in the HTML (the Parquet files hold all)
DPI = 100  # figures are drawn at the size they are shown: 1 pt = 1.39 px
FONT_PT = 8.5  # smallest text in a figure: 11.8 px
MAX_WIDTH_IN = 11.0  # widest figure [in]: 1,100 px, inside the page's 1,200 px column
MEASURE_BY_NAME = {m.name: m for m in MEASURES}
MEASURE_NAMES = {"crashed": "crash rate", "mean_speed": "mean speed",
                 "min_headway_s": "min headway", "min_ttc_s": "min TTC",
                 "rms_jerk": "RMS jerk"}
"""How the report names the measures."""


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": FONT_PT, "axes.titlesize": FONT_PT + 1,
                         "xtick.labelsize": FONT_PT, "ytick.labelsize": FONT_PT,
                         "legend.fontsize": FONT_PT})
    return plt


def _wrap(label: str, width: int = 48) -> str:
    """A label wrapped on whole words (never cut): ``A > B > C`` breaks after ``>``."""
    return "\n".join(textwrap.wrap(str(label), width=width, break_long_words=False,
                                   break_on_hyphens=False)) or str(label)


def _pooled(table: pd.DataFrame) -> pd.DataFrame:
    if table.empty or "env" not in table.columns:
        return table
    env = "all" if (table["env"] == "all").any() else sorted(table["env"].unique())[0]
    return table[table["env"] == env]


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=DPI)
    _plt().close(fig)
    return path


def _unit_label(m: Measure) -> str:
    return "%" if m.name == "crashed" else m.unit.replace("^3", "³")


def _scale(m: Measure) -> float:
    return 100.0 if m.name == "crashed" else 1.0


def _label_heatmap(counts: pd.DataFrame, env: str, folder: Path) -> Path | None:
    sub = counts[counts["env"] == env]
    if sub.empty:
        return None
    plt = _plt()
    policies = sorted(sub["policy"].unique())
    top = sub.groupby("sdl")["share"].sum().sort_values(ascending=False).index[:TOP_LABELS]
    mat = (sub[sub["sdl"].isin(top)].pivot_table(index="sdl", columns="policy",
                                                 values="share", fill_value=0.0)
           .reindex(index=top, columns=policies, fill_value=0.0)).to_numpy()
    names = [_wrap(t, 52) for t in top]
    lines = sum(n.count("\n") + 1 for n in names)
    fig, ax = plt.subplots(figsize=(min(MAX_WIDTH_IN, 5.2 + 1.0 * len(policies)),
                                    1.4 + 0.19 * lines + 0.12 * len(top)),
                           layout="constrained")
    vmax = max(float(mat.max()), 0.05)  # the colour scale is fitted to the shares shown
    im = ax.imshow(mat, aspect="auto", cmap="Blues", vmin=0, vmax=vmax)
    ax.set_xticks(range(len(policies)), policies, rotation=20, ha="right")
    ax.set_yticks(range(len(top)), names)
    for (i, j), v in np.ndenumerate(mat):
        if v > 0:
            ax.text(j, i, f"{v:.0%}", ha="center", va="center",
                    color="white" if v > 0.6 * vmax else "black")
    ax.set_title(f"{env}: share of each policy's episodes with each ego label "
                 f"(top {len(top)})", loc="left")
    fig.colorbar(im, ax=ax, fraction=0.04, pad=0.01, format=lambda x, _: f"{x:.0%}")
    return _save(fig, folder / f"labels_{_slug(env)}.png")


def _interval_plot(ax, names, est, lo, hi, *, color="C0", offset=0.0, label=None):
    y = np.arange(len(names)) + offset
    est, lo, hi = (np.asarray(v, float) for v in (est, lo, hi))
    err = np.vstack([np.clip(est - lo, 0, None), np.clip(hi - est, 0, None)])
    err = np.nan_to_num(err)
    ax.errorbar(est, y, xerr=err, fmt="o", color=color, capsize=3, label=label, ms=4)
    ax.set_yticks(np.arange(len(names)), names)


def _fit(ax, lo, hi, *, floor: float | None = None, ceil: float | None = None) -> None:
    """x limits fitted to the intervals shown, with a margin; clipped to [floor, ceil]."""
    values = np.concatenate([np.asarray(lo, float), np.asarray(hi, float)])
    values = values[np.isfinite(values)]
    if not len(values):
        return
    a, b = float(values.min()), float(values.max())
    pad = max((b - a) * 0.08, 1e-3 if b == a else 0)
    a, b = a - pad, b + pad
    if floor is not None:
        a = max(a, floor)
    if ceil is not None:
        b = min(b, ceil)
    if b > a:
        ax.set_xlim(a, b)


def _measures_plot(scores: Scores, env: str, reference: str, folder: Path) -> Path | None:
    m = scores.measures[scores.measures["env"] == env] if len(scores.measures) else \
        scores.measures
    if m.empty:
        return None
    plt = _plt()
    policies = sorted(m["policy"].unique())
    fig, axes = plt.subplots(1, len(MEASURES), figsize=(MAX_WIDTH_IN, 1.3 + 0.3 * len(policies)),
                             sharey=True, layout="constrained")
    for ax, meas in zip(np.atleast_1d(axes), MEASURES, strict=True):
        sub = m[m["measure"] == meas.name].set_index("policy").reindex(policies)
        k = _scale(meas)
        _interval_plot(ax, policies, sub["mean"] * k, sub["low"] * k, sub["high"] * k)
        ref = sub.loc[reference, "mean"] * k if reference in sub.index else np.nan
        if np.isfinite(ref):
            ax.axvline(ref, color="0.6", lw=0.8, ls="--")
        _fit(ax, sub["low"] * k, sub["high"] * k, floor=0.0,
             ceil=100.0 if meas.name == "crashed" else None)
        better = "higher" if meas.higher_is_better else "lower"
        name = MEASURE_NAMES.get(meas.name, meas.name)
        ax.set_title(f"{name} [{_unit_label(meas)}]\n{better} is better")
        ax.grid(axis="x", alpha=0.3)
    np.atleast_1d(axes)[0].invert_yaxis()
    return _save(fig, folder / f"measures_{_slug(env)}.png")


def _coverage_plot(scores: Scores, folder: Path) -> Path | None:
    cov = _pooled(scores.coverage)
    if cov.empty:
        return None
    plt = _plt()
    refs = sorted(cov["reference"].unique())
    policies = sorted(cov["policy"].unique())
    fig, axes = plt.subplots(1, 2, figsize=(MAX_WIDTH_IN, 1.5 + 0.45 * len(policies)),
                             sharey=True, layout="constrained")
    for k, ref in enumerate(refs):
        sub = cov[cov["reference"] == ref].set_index("policy").reindex(policies)
        off = (k - (len(refs) - 1) / 2) * 0.25
        _interval_plot(axes[0], policies, sub["coverage"] * 100, sub["coverage_low"] * 100,
                       sub["coverage_high"] * 100, color=f"C{k}", offset=off, label=ref)
        _interval_plot(axes[1], policies, sub["weighted_coverage"] * 100,
                       sub["weighted_low"] * 100, sub["weighted_high"] * 100, color=f"C{k}",
                       offset=off, label=ref)
    axes[0].set_title("coverage [%]: share of the reference's labels shown", loc="left")
    axes[1].set_title("frequency-weighted coverage [%]", loc="left")
    _fit(axes[0], cov["coverage_low"] * 100, cov["coverage_high"] * 100, floor=0, ceil=100)
    _fit(axes[1], cov["weighted_low"] * 100, cov["weighted_high"] * 100, floor=0, ceil=100)
    for ax in axes:
        ax.grid(axis="x", alpha=0.3)
    axes[0].invert_yaxis()
    axes[1].legend(loc="best", title="reference")
    return _save(fig, folder / "coverage.png")


def _forest_plots(scores: Scores, folder: Path) -> list[Path]:
    labels = scores.paired_labels
    out: list[Path] = []
    if labels.empty:
        return out
    plt = _plt()
    for (a, b), sub in labels.groupby(["policy_a", "policy_b"], sort=True):
        sub = _pooled(sub)
        sub = sub.reindex(sub["diff"].abs().sort_values(ascending=False).index)[:TOP_LABELS]
        names = [_wrap(t, 60) for t in sub["label"]]
        lines = sum(n.count("\n") + 1 for n in names)
        fig, ax = plt.subplots(figsize=(MAX_WIDTH_IN, 1.3 + 0.2 * lines + 0.1 * len(sub)),
                               layout="constrained")
        y = np.arange(len(sub))
        ax.hlines(y, sub["band_low"] * 100, sub["band_high"] * 100, color="0.85", lw=7,
                  label="simultaneous band")
        _interval_plot(ax, names, sub["diff"] * 100, sub["diff_low"] * 100,
                       sub["diff_high"] * 100, label="95 % interval")
        ax.axvline(0, color="k", lw=0.8)
        _fit(ax, sub["band_low"] * 100, sub["band_high"] * 100, floor=-100, ceil=100)
        ax.invert_yaxis()
        ax.set_xlabel(f"difference in the share of seeds [percentage points]: {a} minus {b}")
        ax.set_title(f"{a} vs {b}, paired by seed (env: {sub['env'].iloc[0]})", loc="left")
        ax.legend(loc="best")
        out.append(_save(fig, folder / f"forest_{_slug(a)}_vs_{_slug(b)}.png"))
    return out


def _improvement_plot(scores: Scores, folder: Path) -> Path | None:
    pm = _pooled(scores.paired_measures)
    if pm.empty:
        return None
    plt = _plt()
    pairs = pm[["policy_a", "policy_b"]].drop_duplicates().to_records(index=False)
    fig, ax = plt.subplots(figsize=(9.5, 1.2 + 0.24 * len(pm)), layout="constrained")
    names = []
    k = 0
    for j, (a, b) in enumerate(pairs):
        sub = pm[(pm["policy_a"] == a) & (pm["policy_b"] == b)]
        for r in sub.itertuples():
            ax.errorbar(r.p_improvement, k, xerr=[[max(r.p_improvement - r.p_low, 0)],
                                                  [max(r.p_high - r.p_improvement, 0)]],
                        fmt="o", color=f"C{j}", capsize=3, ms=4)
            name = MEASURE_NAMES.get(r.measure, r.measure)
            names.append(f"{a} vs {b}: {name}")
            k += 1
    ax.set_yticks(range(len(names)), names)
    ax.axvline(0.5, color="k", lw=0.8)
    ax.set_xlim(-0.02, 1.02)
    ax.invert_yaxis()
    ax.set_xlabel("P(A better than B on the same seed); ties count 1/2; 0.5: no difference")
    return _save(fig, folder / "improvement.png")


def _novelty_plot(scores: Scores, folder: Path) -> Path | None:
    nov = _pooled(scores.novelty)
    if nov.empty:
        return None
    plt = _plt()
    refs = sorted(nov["reference"].unique())
    policies = sorted(nov["policy"].unique())
    fig, ax = plt.subplots(figsize=(9.5, 1.3 + 0.45 * len(policies)), layout="constrained")
    for k, ref in enumerate(refs):
        sub = nov[nov["reference"] == ref].set_index("policy").reindex(policies)
        offset = (k - (len(refs) - 1) / 2) * 0.25
        _interval_plot(ax, policies, sub["novel_rate"] * 100, sub["novel_low"] * 100,
                       sub["novel_high"] * 100, color=f"C{k}", offset=offset, label=ref)
    _fit(ax, nov["novel_low"] * 100, nov["novel_high"] * 100, floor=0, ceil=100)
    ax.invert_yaxis()
    ax.set_xlabel("novelty rate [%]: share of episodes whose ego label the reference never shows")
    ax.legend(loc="best", title="reference")
    ax.grid(axis="x", alpha=0.3)
    return _save(fig, folder / "novelty.png")


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in str(name))


def _envs(scores: Scores) -> list[str]:
    envs = set()
    for table in (scores.measures, scores.label_counts):
        if len(table) and "env" in table.columns:
            envs |= set(map(str, table["env"].unique()))
    envs.discard("all")
    return sorted(envs)


def write_plots(scores: Scores, folder: str | os.PathLike, *,
                reference: str | None = None) -> list[Path]:
    """Write the PNG plots of a scored run into ``folder`` and return their paths.

    Per env: ``labels_<env>.png`` (label heat map) and ``measures_<env>.png``; pooled:
    ``measures_all.png``, ``improvement.png``, ``coverage.png``, ``forest_<A>_vs_<B>.png``,
    ``novelty.png``.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    reference = reference or ""
    paths: list[Path | None] = []
    envs = _envs(scores)
    for env in envs:
        paths.append(_label_heatmap(scores.label_counts, env, folder))
        paths.append(_measures_plot(scores, env, reference, folder))
    if len(envs) > 1:
        paths.append(_measures_plot(scores, "all", reference, folder))
    paths += [_improvement_plot(scores, folder), _coverage_plot(scores, folder),
              *_forest_plots(scores, folder), _novelty_plot(scores, folder)]
    return [p for p in paths if p is not None]


# -- numbers --------------------------------------------------------------------------------

def _num(value: Any, decimals: int) -> str:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return "–"
    if not np.isfinite(v):
        return "–"
    text = f"{v:.{decimals}f}"
    return "0" + (f".{'0' * decimals}" if decimals else "") if text.lstrip("-") == \
        f"{0:.{decimals}f}" else text  # no "-0.00"


def _pct(value: Any, decimals: int = 0) -> str:
    try:
        return _num(float(value) * 100, decimals) + " %"
    except (TypeError, ValueError):
        return "–"


def _measure_value(m: Measure, value: Any) -> str:
    """A measure's value in its unit, to its precision (crash rates in %)."""
    if m.name == "crashed":
        return _pct(value)
    decimals = 1 if m.name == "mean_speed" else 2
    return f"{_num(value, decimals)} {_unit_label(m)}"


def _interval(lo: str, hi: str) -> str:
    return f"[{lo}, {hi}]" if lo != "–" or hi != "–" else ""


def _measure_interval(m: Measure, lo: Any, hi: Any) -> str:
    if m.name == "crashed":
        return _interval(_pct(lo), _pct(hi))
    decimals = 1 if m.name == "mean_speed" else 2
    return _interval(_num(lo, decimals), _num(hi, decimals))


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
figure{margin:.6em 0}img{border:1px solid #eee;max-width:100%;height:auto}
figcaption{font-size:13px;color:#444;max-width:60em}
.note{color:#555;font-size:13px}.fail{color:#a00}
a.replay{white-space:nowrap}
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
            text, attrs = v if isinstance(v, tuple) and len(v) == 2 and isinstance(v[1], dict) \
                else (_cell_text(v), {})
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


def _figure(path: Path, alt: str, caption: str) -> str:
    from PIL import Image

    with Image.open(path) as im:
        width, height = im.size
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (f'<figure><img src="data:image/png;base64,{data}" alt="{html.escape(alt)}" '
            f'width="{width}" height="{height}"><figcaption>{html.escape(caption)}'
            "</figcaption></figure>")


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
            name = MEASURE_NAMES.get(meas.name, meas.name)
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
                if c.empty:
                    row[f"{what} {ref}"] = ("–", {})
                    continue
                c = c.iloc[0]
                row[f"{what} {ref}"] = (f"{_pct(c[est])}\n{_interval(_pct(c[lo]), _pct(c[hi]))}",
                                        {"v": float(c[est])})
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


def _display_measures(table: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for r in table.itertuples(index=False):
        meas = MEASURE_BY_NAME.get(r.measure)
        if meas is None:
            continue
        rows.append({"env": r.env, "policy": r.policy,
                     "measure": MEASURE_NAMES.get(meas.name, meas.name),
                     "n": r.n, "mean": (_measure_value(meas, r.mean), {"v": r.mean}),
                     "95 % interval": _measure_interval(meas, r.low, r.high)})
    return pd.DataFrame(rows)


def _display_paired_measures(table: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for r in table.itertuples(index=False):
        meas = MEASURE_BY_NAME.get(r.measure)
        if meas is None:
            continue
        mark, cls = _mark(r.diff_low, r.diff_high, meas.higher_is_better)
        rows.append({"env": r.env, "A": r.policy_a, "B": r.policy_b,
                     "measure": MEASURE_NAMES.get(meas.name, meas.name),
                     "pairs": r.n, "mean A": _measure_value(meas, r.mean_a),
                     "mean B": _measure_value(meas, r.mean_b),
                     "A − B": (_measure_value(meas, r.diff), {"v": r.diff}),
                     "95 % interval": _measure_interval(meas, r.diff_low, r.diff_high),
                     "A vs B": (mark, {"class": cls}),
                     "P(A better)": (f"{_num(r.p_improvement, 2)} "
                                     f"{_interval(_num(r.p_low, 2), _num(r.p_high, 2))}",
                                     {"v": r.p_improvement})})
    return pd.DataFrame(rows)


def _display_paired(table: pd.DataFrame) -> pd.DataFrame:
    return pd.DataFrame([{
        "env": r.env, "A": r.policy_a, "B": r.policy_b, "pairs": r.n_pairs,
        "dropped": r.n_dropped, "same label": (_pct(r.agreement), {"v": r.agreement}),
        "95 % interval": _interval(_pct(r.agreement_low), _pct(r.agreement_high))}
        for r in table.itertuples(index=False)])


def _display_paired_labels(table: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for r in table.itertuples(index=False):
        mark, cls = _mark(r.diff_low, r.diff_high, True)
        mark = {"better": "▲ A more often", "worse": "▼ A less often"}.get(cls, mark)
        rows.append({"env": r.env, "A": r.policy_a, "B": r.policy_b, "label": r.label,
                     "share A": _pct(r.freq_a), "share B": _pct(r.freq_b),
                     "A − B [pp]": (_num(r.diff * 100, 1), {"v": r.diff}),
                     "95 % interval": _interval(_num(r.diff_low * 100, 1),
                                                _num(r.diff_high * 100, 1)),
                     "band": _interval(_num(r.band_low * 100, 1), _num(r.band_high * 100, 1)),
                     "": (mark, {"class": cls})})
    return pd.DataFrame(rows)


def _display_matched(table: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for r in table.itertuples(index=False):
        meas = MEASURE_BY_NAME.get(r.measure)
        if meas is None:  # a group too small to test: listed with its sizes
            if getattr(r, "note", ""):
                rows.append({"env": r.env, "label": r.label, "A": r.policy_a,
                             "B": r.policy_b, "episodes A": r.n_a, "episodes B": r.n_b,
                             "measure": "–", "A vs B": r.note})
            continue
        mark, cls = _mark(r.diff_low, r.diff_high, meas.higher_is_better)
        rows.append({"env": r.env, "label": r.label, "A": r.policy_a, "B": r.policy_b,
                     "episodes A": r.n_a, "episodes B": r.n_b,
                     "measure": MEASURE_NAMES.get(meas.name, meas.name),
                     "mean A": _measure_value(meas, r.mean_a),
                     "mean B": _measure_value(meas, r.mean_b),
                     "A − B": (_measure_value(meas, r.diff), {"v": r.diff}),
                     "95 % interval": _measure_interval(meas, r.diff_low, r.diff_high),
                     "A vs B": (mark, {"class": cls})})
    return pd.DataFrame(rows)


def _display_coverage(table: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for r in table.to_dict("records"):
        row = {"env": r["env"], "policy": r["policy"], "reference": r["reference"],
               "episodes": r["n"],
               "coverage": (_pct(r["coverage"]), {"v": r["coverage"]}),
               "95 % interval": _interval(_pct(r["coverage_low"]), _pct(r["coverage_high"])),
               "weighted": (_pct(r["weighted_coverage"]), {"v": r["weighted_coverage"]}),
               "weighted interval": _interval(_pct(r["weighted_low"]), _pct(r["weighted_high"])),
               "distinct labels": r.get("n_distinct")}
        for key in r:  # diversity figures as the scoring gives them (bits, Hill numbers ...)
            if key not in row and key not in ("n", "coverage_low", "coverage_high",
                                              "weighted_coverage", "weighted_low",
                                              "weighted_high", "n_distinct", "coverage"):
                row[key] = (_num(r[key], 2), {"v": r[key]}) if isinstance(
                    r[key], float | np.floating) else r[key]
        rows.append(row)
    return pd.DataFrame(rows)


def _display_novelty(table: pd.DataFrame) -> pd.DataFrame:
    return pd.DataFrame([{
        "env": r.env, "policy": r.policy, "reference": r.reference, "episodes": r.n,
        "novel episodes": r.n_novel, "novelty rate": (_pct(r.novel_rate), {"v": r.novel_rate}),
        "95 % interval": _interval(_pct(r.novel_low), _pct(r.novel_high)),
        "novel labels": r.n_novel_labels, "reference size": r.reference_size}
        for r in table.itertuples(index=False)])


def _display_novel_labels(table: pd.DataFrame) -> pd.DataFrame:
    return pd.DataFrame([{
        "env": r.env, "policy": r.policy, "reference": r.reference, "label": r.label,
        "episodes": r.count, "share": (_pct(r.share, 1), {"v": r.share}),
        "example": r.example_scenario} for r in table.itertuples(index=False)])


def _replay(viewer: str | None, **params: Any) -> str | None:
    if viewer is None:
        return None
    parts = [f"{k}={quote(str(v), safe='')}" for k, v in params.items()
             if v is not None and v != ""]
    return f"{viewer}#{'&'.join(parts)}"


def write_report(folder: str | os.PathLike, summary: dict[str, Any], episodes: pd.DataFrame,
                 scores: Scores, *, viewer: str | None = None) -> Path:
    """Write ``plots/*.png`` and ``report.html`` into a run folder; returns the HTML path.

    Args:
        folder: the run folder.
        summary: the run's ``summary.json`` content.
        episodes: the episode table.
        scores: the scored tables.
        viewer: the replay viewer's page relative to the report (``viewer/index.html``):
            rows naming episodes or labels link to their replay; None: no links.
    """
    folder = Path(folder)
    reference = str(summary.get("reference_policy", ""))
    plots = {p.stem: p for p in write_plots(scores, folder / "plots", reference=reference)}
    suite = summary.get("suite", {})
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

    def img(name: str, alt: str, caption: str) -> str:
        return _figure(plots[name], alt, caption) if name in plots else ""

    # 1. the summary
    pooled_env = "all" if len(_envs(scores)) > 1 else (_envs(scores) or ["–"])[0]
    parts.append("<h2>Summary: each policy against the reference</h2>")
    parts.append(html_table(
        summary_table(scores, reference), table_id="summary", max_rows=50,
        caption=f"Env: {pooled_env}. Each cell: the policy's mean over episodes, its 95 % "
        "interval in brackets, and its paired difference from the reference policy "
        f"{reference} on the same seeds: ▲ better or ▼ worse when the difference's 95 % "
        "interval excludes 0, = no difference otherwise. Crash rate in % of episodes; min "
        "headway and min TTC are each episode's smallest values (capped at 10 s); coverage: "
        "share of the reference corpus's labels the policy shows; novel: share of episodes "
        "whose label the reference never shows."))
    if scores.methods:
        parts.append('<details><summary class="note">How the intervals are computed</summary>'
                     "<ul>" + "".join(f"<li><b>{html.escape(k)}</b>: {html.escape(v)}</li>"
                                      for k, v in scores.methods.items()) + "</ul></details>")

    # 2. per-env panels
    parts.append("<h2>Per env</h2>")
    for env in _envs(scores):
        parts.append(f'<h3 id="env-{html.escape(_slug(env))}">{html.escape(env)}</h3>')
        parts.append(img(
            f"measures_{_slug(env)}", f"measures in {env}",
            f"Safety and efficiency in {env}: each policy's mean over its episodes (dot) and "
            "95 % interval (bar), one panel per measure; the dashed line is the reference "
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
            parts.append(html_table(
                crashed[["policy", "seed", "sdl"]].rename(columns={"sdl": "ego label"}),
                table_id=f"crashed-{_slug(env)}", text_columns=("ego label",),
                caption=f"Crashed episodes in {env}: the ego collided.",
                links=[_replay(viewer, ep=r.scenario_id, b=reference)
                       for r in crashed.itertuples()]))
    if "all" in set(scores.measures.get("env", [])):
        parts.append("<h3>All envs pooled</h3>")
        parts.append(img("measures_all", "measures pooled over envs",
                         "All envs pooled (each env resampled on its own, so each keeps its "
                         "weight): means and 95 % intervals as above."))
    parts.append(html_table(_display_measures(scores.measures), table_id="measures",
                            caption="Every measure per env and policy: mean over episodes and "
                            "95 % interval, in the measure's unit."))

    # 3. comparisons in detail
    parts.append("<h2>Matched comparison: paired by seed</h2>")
    parts.append('<p class="note">Each policy against the reference on the same initial '
                 "traffic (the same seed).</p>")
    parts.append(html_table(_display_paired(scores.paired), table_id="paired",
                            caption="Share of seeds on which A's and B's egos carry the same "
                            "label."))
    parts.append(img("improvement", "probability of improvement",
                     "Probability that A does better than B on the same seed (ties count one "
                     "half), per measure, with 95 % intervals, all envs pooled. 0.5 is no "
                     "difference; right of it A is better."))
    parts.append(html_table(_display_paired_measures(scores.paired_measures),
                            table_id="paired_measures",
                            caption="Measures paired by seed: means of A and B, the mean "
                            "paired difference A − B in the measure's unit with its 95 % "
                            "interval, and P(A better)."))
    for key in sorted(k for k in plots if k.startswith("forest_")):
        parts.append(img(key, f"forest plot {key}",
                         "Label frequencies paired by seed: for the labels that differ most, "
                         "the share of seeds on which A shows the label minus the share for "
                         "B, in percentage points (dot, 95 % interval as a bar); the grey "
                         "band is the simultaneous band over all labels: a label whose band "
                         "excludes 0 differs even after looking at every label."))
    pl = scores.paired_labels
    parts.append(html_table(
        _display_paired_labels(pl), table_id="paired_labels", text_columns=("label",),
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
        _display_matched(mt), table_id="matched", text_columns=("label",),
        caption="Inside each group of episodes with the same ego label in one env (both "
        "policies present): the measures of A and B compared (unpaired, 95 % intervals); "
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
    parts.append("<h2>Behaviour coverage</h2>")
    parts.append(img("coverage", "coverage",
                     "Coverage, all envs pooled: the share of the reference corpus's labels "
                     "each policy shows (left) and the same weighted by how often the "
                     "reference shows each label (right), with 95 % intervals; one colour "
                     "per reference corpus."))
    parts.append(html_table(_display_coverage(scores.coverage), table_id="coverage",
                            caption="Coverage per env and reference, with the diversity of "
                            "each policy's labels."))
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
                     "whose ego label the reference corpus never shows, with 95 % "
                     "intervals; one colour per reference."))
    parts.append(html_table(_display_novelty(scores.novelty), table_id="novelty",
                            caption="Novelty per env and reference."))
    nl = scores.novel_labels
    parts.append(html_table(
        _display_novel_labels(nl), table_id="novel_labels", text_columns=("label", "example"),
        caption="Novel labels with an example episode; replay opens the example beside the "
        "reference policy on the same seed.",
        links=[_replay(viewer, ep=r.example_scenario, b=reference)
               for r in nl.itertuples()] if len(nl) else None))
    if not scores.scenario_matches.empty:
        parts.append("<h2>Scenarios matched across data sets</h2>")
        parts.append(html_table(scores.scenario_matches, table_id="scenario_matches",
                                caption="Each simulated episode beside its nearest WOMD "
                                "scenarios by scenario-level SDL (Scenario2Vector distance)."))

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

    # 4. the run
    parts.append("<h2>The run</h2>")
    facts = pd.DataFrame([
        ("envs", ", ".join(suite.get("envs", []))),
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
    timings = summary.get("timings", {})
    if timings:
        parts.append("<h3>Timings</h3>")
        parts.append(html_table(
            pd.DataFrame({"stage": list(timings),
                          "seconds": [f"{v:.1f} s" for v in timings.values()]}),
            table_id="timings", max_rows=50,
            caption="Wall time per stage; *_cpu_in_workers add up over the worker processes."))
    page = ("<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<link rel=\"icon\" href=\"data:,\">"
            f"<title>tap-bench {html.escape(run)}</title>"
            f"<style>{_CSS}</style></head><body>{''.join(parts)}"
            f"<script>{_SCRIPT}</script></body></html>\n")
    path = folder / "report.html"
    with atomic_path(path) as tmp:
        tmp.write_text(page, encoding="utf-8")
    return path


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
        row["completeness"] = (f"{r['completeness']:.0%} [{r['completeness_low']:.0%}, "
                               f"{r['completeness_high']:.0%}]")
        asym = ", ".join(f"{r[f'asymptote_q{q}']:.1f}" for q in (0, 1, 2))
        row["whole distribution (q0, q1, q2)"] = (f"at least {asym}" if r["asymptote_is_bound"]
                                                  else asym)
        rows.append(row)
    return pd.DataFrame(rows)


def _seed_text(seeds: list[int]) -> str:
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

