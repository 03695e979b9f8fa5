"""The run report: PNG plots and one static HTML page (no server, no script).

:func:`write_report` writes ``plots/*.png`` and ``report.html`` into a run folder. The page
embeds its images as data URIs, so the HTML file alone is the whole report (mail it, open
it from disk); the PNG files are there for papers and slides.

Plots: ego label distribution per env and policy (heat map), safety and efficiency
measures with intervals, coverage of each reference with intervals, paired label
differences as forest plots (percentile intervals and the simultaneous band), the
probability that each policy beats the reference policy per measure, and novelty rates.
"""

from __future__ import annotations

import base64
import html
import os
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tap_bench.bench.measures import MEASURES
from tap_bench.bench.scoring import Scores
from tap_bench.tableio import atomic_path

__all__ = ["write_plots", "write_report"]

TOP_LABELS = 12  # labels shown per heat map and forest plot
TABLE_ROWS = 40  # rows shown per long table in the HTML (the Parquet files hold all)


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def _short(label: str, width: int = 60) -> str:
    return textwrap.shorten(str(label), width=width, placeholder=" ...")


def _pooled(table: pd.DataFrame) -> pd.DataFrame:
    if table.empty or "env" not in table.columns:
        return table
    env = "all" if (table["env"] == "all").any() else sorted(table["env"].unique())[0]
    return table[table["env"] == env]


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=110, bbox_inches="tight")
    _plt().close(fig)
    return path


def _label_heatmaps(scores: Scores, folder: Path) -> Path | None:
    counts = scores.label_counts
    if counts.empty:
        return None
    plt = _plt()
    envs = sorted(counts["env"].unique())
    policies = sorted(counts["policy"].unique())
    fig, axes = plt.subplots(len(envs), 1, figsize=(2.2 + 1.1 * len(policies) + 4.5,
                                                     1.2 + 3.6 * len(envs)), squeeze=False,
                             layout="constrained")
    for ax, env in zip(axes[:, 0], envs, strict=True):
        sub = counts[counts["env"] == env]
        top = sub.groupby("sdl")["share"].sum().sort_values(ascending=False).index[:TOP_LABELS]
        mat = (sub[sub["sdl"].isin(top)].pivot_table(index="sdl", columns="policy",
                                                     values="share", fill_value=0.0)
               .reindex(index=top, columns=policies, fill_value=0.0))
        im = ax.imshow(mat.to_numpy(), aspect="auto", cmap="viridis", vmin=0, vmax=1)
        ax.set_xticks(range(len(policies)), policies, rotation=30, ha="right", fontsize=8)
        ax.set_yticks(range(len(top)), [_short(t) for t in top], fontsize=7)
        for (i, j), v in np.ndenumerate(mat.to_numpy()):
            if v > 0:
                ax.text(j, i, f"{v:.0%}", ha="center", va="center", fontsize=6,
                        color="white" if v < 0.6 else "black")
        ax.set_title(f"{env}: share of episodes with each ego label (top {len(top)})",
                     fontsize=9)
        fig.colorbar(im, ax=ax, fraction=0.02, pad=0.01)
    return _save(fig, folder / "label_distribution.png")


def _interval_plot(ax, names, est, lo, hi, *, color="C0", offset=0.0, label=None):
    y = np.arange(len(names)) + offset
    est, lo, hi = (np.asarray(v, float) for v in (est, lo, hi))
    err = np.vstack([np.clip(est - lo, 0, None), np.clip(hi - est, 0, None)])
    err = np.nan_to_num(err)
    ax.errorbar(est, y, xerr=err, fmt="o", color=color, capsize=3, label=label, ms=4)
    ax.set_yticks(np.arange(len(names)), names, fontsize=8)


def _measures_plot(scores: Scores, folder: Path) -> Path | None:
    m = _pooled(scores.measures)
    if m.empty:
        return None
    plt = _plt()
    fig, axes = plt.subplots(1, len(MEASURES), figsize=(3.2 * len(MEASURES), 0.5 + 0.45 *
                                                       m["policy"].nunique() + 1),
                             layout="constrained")
    for ax, meas in zip(np.atleast_1d(axes), MEASURES, strict=True):
        sub = m[m["measure"] == meas.name].sort_values("policy")
        _interval_plot(ax, sub["policy"].tolist(), sub["mean"], sub["low"], sub["high"])
        better = "higher" if meas.higher_is_better else "lower"
        ax.set_title(f"{meas.name} [{meas.unit}]\n({better} is better)", fontsize=8)
        ax.grid(axis="x", alpha=0.3)
    fig.suptitle(f"Safety and efficiency per policy (env: {m['env'].iloc[0]}), 95 % intervals",
                 fontsize=9)
    return _save(fig, folder / "measures.png")


def _coverage_plot(scores: Scores, folder: Path) -> Path | None:
    cov = _pooled(scores.coverage)
    if cov.empty:
        return None
    plt = _plt()
    refs = sorted(cov["reference"].unique())
    fig, axes = plt.subplots(1, 2, figsize=(10, 1.5 + 0.5 * cov["policy"].nunique() * len(refs)),
                             layout="constrained")
    for k, ref in enumerate(refs):
        sub = cov[cov["reference"] == ref].sort_values("policy")
        off = (k - (len(refs) - 1) / 2) * 0.25
        _interval_plot(axes[0], sub["policy"].tolist(), sub["coverage"], sub["coverage_low"],
                       sub["coverage_high"], color=f"C{k}", offset=off, label=ref)
        _interval_plot(axes[1], sub["policy"].tolist(), sub["weighted_coverage"],
                       sub["weighted_low"], sub["weighted_high"], color=f"C{k}", offset=off,
                       label=ref)
    axes[0].set_title("coverage: share of the reference's labels shown", fontsize=9)
    axes[1].set_title("frequency-weighted coverage", fontsize=9)
    for ax in axes:
        ax.set_xlim(-0.02, 1.02)
        ax.grid(axis="x", alpha=0.3)
    axes[1].legend(fontsize=7, loc="lower right")
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
        sub = sub.iloc[::-1]
        fig, ax = plt.subplots(figsize=(9, 1 + 0.4 * len(sub)))
        y = np.arange(len(sub))
        ax.hlines(y, sub["band_low"], sub["band_high"], color="0.8", lw=6,
                  label="simultaneous band")
        _interval_plot(ax, [_short(t, 70) for t in sub["label"]], sub["diff"], sub["diff_low"],
                       sub["diff_high"], label="95 % interval")
        ax.axvline(0, color="k", lw=0.8)
        ax.set_xlabel(f"share of seeds: {a} minus {b}")
        ax.set_title(f"Paired by seed: ego label frequency differences, {a} vs {b} "
                     f"(env: {sub['env'].iloc[0]})", fontsize=9)
        ax.legend(fontsize=7, loc="lower right")
        out.append(_save(fig, folder / f"forest_{_slug(a)}_vs_{_slug(b)}.png"))
    return out


def _improvement_plot(scores: Scores, folder: Path) -> Path | None:
    pm = _pooled(scores.paired_measures)
    if pm.empty:
        return None
    plt = _plt()
    pairs = pm[["policy_a", "policy_b"]].drop_duplicates().to_records(index=False)
    fig, ax = plt.subplots(figsize=(8, 1 + 0.3 * len(pm)))
    names = []
    k = 0
    for j, (a, b) in enumerate(pairs):
        sub = pm[(pm["policy_a"] == a) & (pm["policy_b"] == b)]
        for r in sub.itertuples():
            ax.errorbar(r.p_improvement, k, xerr=[[max(r.p_improvement - r.p_low, 0)],
                                                  [max(r.p_high - r.p_improvement, 0)]],
                        fmt="o", color=f"C{j}", capsize=3, ms=4)
            names.append(f"{a} vs {b}: {r.measure}")
            k += 1
    ax.set_yticks(range(len(names)), names, fontsize=7)
    ax.axvline(0.5, color="k", lw=0.8)
    ax.set_xlim(-0.02, 1.02)
    ax.invert_yaxis()
    ax.set_xlabel("P(A better than B on the same seed), ties count 1/2")
    ax.set_title("Probability of improvement, paired by seed, 95 % intervals", fontsize=9)
    return _save(fig, folder / "improvement.png")


def _novelty_plot(scores: Scores, folder: Path) -> Path | None:
    nov = _pooled(scores.novelty)
    if nov.empty:
        return None
    plt = _plt()
    refs = sorted(nov["reference"].unique())
    fig, ax = plt.subplots(figsize=(9, 1.2 + 0.7 * nov["policy"].nunique() * len(refs)))
    examples = _pooled(scores.novel_labels)
    for k, ref in enumerate(refs):
        sub = nov[nov["reference"] == ref].sort_values("policy")
        offset = (k - (len(refs) - 1) / 2) * 0.25
        _interval_plot(ax, sub["policy"].tolist(), sub["novel_rate"], sub["novel_low"],
                       sub["novel_high"], color=f"C{k}", offset=offset, label=ref)
        for y, policy in enumerate(sub["policy"]):  # the most frequent novel label, as text
            ex = examples[(examples["reference"] == ref) & (examples["policy"] == policy)] \
                if len(examples) else examples
            if len(ex):
                top = ex.sort_values("count", ascending=False).iloc[0]
                ax.annotate(f"e.g. {_short(top['label'], 55)} ({top['count']}x)",
                            (0.01, y + offset - 0.22), fontsize=6, color=f"C{k}",
                            xycoords=("axes fraction", "data"))
    ax.set_xlim(-0.02, 1.02)
    ax.set_ylim(-0.6, nov["policy"].nunique() - 0.5)
    ax.set_xlabel("share of episodes whose ego label the reference never shows")
    ax.set_title("Unique manoeuvres (novelty rate), 95 % intervals, with the most frequent "
                 "novel label", fontsize=9)
    ax.legend(fontsize=7, loc="lower right")
    return _save(fig, folder / "novelty.png")


def _slug(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in str(name))


def write_plots(scores: Scores, folder: str | os.PathLike) -> list[Path]:
    """Write the PNG plots of a scored run into ``folder`` and return their paths."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = [_label_heatmaps(scores, folder), _measures_plot(scores, folder),
             _improvement_plot(scores, folder), _coverage_plot(scores, folder),
             *_forest_plots(scores, folder), _novelty_plot(scores, folder)]
    return [p for p in paths if p is not None]


# -- HTML ---------------------------------------------------------------------------------

_CSS = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1200px;color:#222;padding:0 1em}
h1{font-size:1.6em}h2{font-size:1.25em;margin-top:2em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;font-size:.82em;margin:.6em 0}
th,td{border:1px solid #ddd;padding:.25em .5em;text-align:right}
th{background:#f3f3f3}td.l,th.l{text-align:left}td.l{max-width:36em;overflow-wrap:anywhere}
img{max-width:100%;border:1px solid #eee;margin:.5em 0}
.note{color:#555;font-size:.9em}.fail{color:#a00}
"""


def _fmt(value: Any) -> str:
    if isinstance(value, bool | np.bool_):
        return "yes" if value else "no"
    if isinstance(value, float | np.floating):
        if not np.isfinite(value):
            return "–"
        return f"{value:.3g}" if abs(value) >= 1e-3 or value == 0 else f"{value:.2e}"
    if value is None or value is pd.NA:
        return "–"
    return str(value)


def html_table(table: pd.DataFrame, *, caption: str = "", max_rows: int = TABLE_ROWS,
               table_id: str = "") -> str:
    """A DataFrame as an escaped HTML table (text columns left-aligned), first rows only."""
    if table.empty:
        return '<p class="note">(nothing to show)</p>'
    shown = table.head(max_rows)
    text_cols = {c for c in shown.columns if shown[c].dtype == object
                 or str(shown[c].dtype).startswith("string")}
    head = "".join(f'<th class="{"l" if c in text_cols else ""}">{html.escape(str(c))}</th>'
                   for c in shown.columns)
    body = []
    for row in shown.itertuples(index=False):
        cells = "".join(
            f'<td class="{"l" if c in text_cols else ""}">{html.escape(_fmt(v))}</td>'
            for c, v in zip(shown.columns, row, strict=True))
        body.append(f"<tr>{cells}</tr>")
    more = (f'<p class="note">first {max_rows} of {len(table)} rows; the Parquet file has '
            "all</p>") if len(table) > max_rows else ""
    cap = f"<caption>{html.escape(caption)}</caption>" if caption else ""
    ident = f' id="{table_id}"' if table_id else ""
    return (f"<table{ident}>{cap}<thead><tr>{head}</tr></thead><tbody>{''.join(body)}"
            f"</tbody></table>{more}")


def _img(path: Path, alt: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return (f'<figure><img src="data:image/png;base64,{data}" alt="{html.escape(alt)}">'
            f"<figcaption class=\"note\">{html.escape(path.name)}</figcaption></figure>")


def write_report(folder: str | os.PathLike, summary: dict[str, Any], episodes: pd.DataFrame,
                 scores: Scores) -> Path:
    """Write ``plots/*.png`` and ``report.html`` into a run folder; returns the HTML path."""
    folder = Path(folder)
    plots = {p.stem: p for p in write_plots(scores, folder / "plots")}
    suite = summary.get("suite", {})
    parts = [f"<h1>tap-bench run {html.escape(str(summary.get('run', '')))}</h1>",
             f"<p>Suite <b>{html.escape(str(suite.get('name', '')))}</b> "
             f"(v{suite.get('version', 0)}): {html.escape(str(suite.get('description', '')))}"
             "</p>"]
    facts = pd.DataFrame([
        ("envs", ", ".join(suite.get("envs", []))),
        ("policies", ", ".join(suite.get("policies", []))),
        ("seeds", _seed_text(summary.get("seeds", []))),
        ("SDL level", summary.get("level", "")),
        ("thresholds", _thresholds_text(summary.get("thresholds"))),
        ("reference policy", summary.get("reference_policy", "")),
        ("references", "; ".join(
            f"{name}: " + (", ".join(Path(p).name for p in src) if isinstance(src, list)
                           else Path(str(src)).name)
            for name, src in summary.get("references", {}).items()) or "–"),
        ("episodes", f"{summary.get('n_episodes', len(episodes))} "
                     f"({summary.get('n_failed', 0)} failed)"),
        ("created", summary.get("created", "")),
        ("versions", ", ".join(f"{k} {v}" for k, v in summary.get("versions", {}).items())),
    ], columns=["what", "value"])
    parts.append(html_table(facts, table_id="facts"))
    methods = summary.get("methods", {})
    if methods:
        parts.append("<h2>How intervals are computed</h2><ul>" + "".join(
            f"<li><b>{html.escape(k)}</b>: {html.escape(v)}</li>" for k, v in methods.items())
            + "</ul>")

    def section(title: str, note: str, *blocks: str) -> None:
        parts.append(f"<h2>{html.escape(title)}</h2>")
        if note:
            parts.append(f'<p class="note">{html.escape(note)}</p>')
        parts.extend(b for b in blocks if b)

    def img(name: str, alt: str) -> str:
        return _img(plots[name], alt) if name in plots else ""

    section("Behaviour: ego label distributions",
            "Share of each policy's episodes whose ego carries each SDL label, per env.",
            img("label_distribution", "label distribution heat map"))
    section("Safety and efficiency", "Means over episodes with percentile bootstrap "
            "intervals; 'all' pools the envs (resampling within each env).",
            img("measures", "measures per policy"),
            html_table(_pooled(scores.measures), table_id="measures"))
    section("Matched comparison: paired by seed", "Each policy against the reference policy on "
            "the same initial traffic. agreement: share of seeds with the same ego label.",
            html_table(scores.paired, table_id="paired"),
            img("improvement", "probability of improvement"),
            html_table(_pooled(scores.paired_measures), table_id="paired_measures"),
            *(img(k, f"forest plot {k}") for k in sorted(plots) if k.startswith("forest_")),
            html_table(scores.paired_labels, table_id="paired_labels"))
    section("Matched comparison: by SDL label", "Inside each group of episodes with the same "
            "ego label in one env (both policies present), the measures compared.",
            html_table(scores.matched, table_id="matched"))
    section("Behaviour coverage", "Share of the reference's labels each policy shows, "
            "frequency-weighted too, and the entropy of its labels.",
            img("coverage", "coverage"), html_table(scores.coverage, table_id="coverage"))
    section("Unique manoeuvres", "Labels a policy shows that the reference never does.",
            img("novelty", "novelty"), html_table(scores.novelty, table_id="novelty"),
            html_table(scores.novel_labels, caption="novel labels with an example episode",
                       table_id="novel_labels"))
    if not scores.scenario_matches.empty:
        section("Scenarios matched across data sets", "Each simulated episode beside its "
                "nearest WOMD scenarios by scenario-level SDL (Scenario2Vector distance).",
                html_table(scores.scenario_matches, table_id="scenario_matches"))
    failed = episodes[episodes["status"] != "ok"]
    section("Failed episodes", "Left out of every score.",
            html_table(failed[["env", "policy", "seed", "error"]], table_id="failed")
            if len(failed) else '<p class="note">none</p>')
    timings = summary.get("timings", {})
    if timings:
        section("Timings", "Seconds; *_cpu_in_workers add up over the worker processes.",
                html_table(pd.DataFrame({"stage": list(timings),
                                         "seconds": [round(v, 2) for v in timings.values()]}),
                           table_id="timings"))
    page = ("<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>tap-bench {html.escape(str(summary.get('run', '')))}</title>"
            f"<style>{_CSS}</style></head><body>{''.join(parts)}</body></html>\n")
    path = folder / "report.html"
    with atomic_path(path) as tmp:
        tmp.write_text(page, encoding="utf-8")
    return path


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
