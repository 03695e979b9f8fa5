"""The run report's figures as SVG, drawn at the size they are shown (text at least 11 px),
scales fitted to the data, labels whole: label heat maps, measures, coverage, forest plots,
improvement over the reference, novelty, drawn from the scores alone
(:func:`draw_figures`: file name -> SVG bytes); the page writes them beside ``report.html``
(:func:`tap_bench.bench.report.page.write_plots`).

The figures are written as SVG text directly (dots, bars, lines, cells and text; no
plotting library): the page embeds them inline, they stay sharp at any zoom, and drawing
all of a demo's figures costs milliseconds where drawing them with matplotlib cost seconds
(``benchmarks/bench_demo.py``).
"""

from __future__ import annotations

import html
import itertools
import math
import textwrap

import numpy as np
import pandas as pd

from tap_bench.bench.measures import MEASURES, Measure, measures_with_role
from tap_bench.bench.report.tables import (
    _pooled,
    _slug,
    interval_heading,
)
from tap_bench.bench.scores.scoring import Scores

TOP_LABELS = 12  # labels shown per heat map and forest plot
FONT_PX = 12  # smallest text in a figure [px]
MAX_WIDTH_PX = 1100  # widest figure, inside the page's 1,200 px column
COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
          "#7f7f7f", "#bcbd22", "#17becf")
"""The series colours (matplotlib's tab10)."""
_BLUES = ((0.0, (247, 251, 255)), (0.125, (222, 235, 247)), (0.25, (198, 219, 239)),
          (0.375, (158, 202, 225)), (0.5, (107, 174, 214)), (0.625, (66, 146, 198)),
          (0.75, (33, 113, 181)), (0.875, (8, 81, 156)), (1.0, (8, 48, 107)))
"""The heat maps' colour scale (ColorBrewer's Blues)."""
_LINE = FONT_PX + 3  # height of a text line [px]


MOVED_NAMES = {"write_plots": "tap_bench.bench.report.page"}
"""Names that left this module, and the module each is in now."""


def __getattr__(name: str):
    """An import of a name that moved out of this module names where it is now."""
    if name in MOVED_NAMES:
        raise ImportError(f"{name} moved from {__name__} to {MOVED_NAMES[name]}: "
                          f"from {MOVED_NAMES[name]} import {name}", name=__name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _wrap(label: str, width: int = 48) -> str:
    """A label wrapped on whole words (never cut): ``A > B > C`` breaks after ``>``."""
    return "\n".join(textwrap.wrap(str(label), width=width, break_long_words=False,
                                   break_on_hyphens=False)) or str(label)


def _text_width(text: str, size: float = FONT_PX) -> float:
    """Estimated width of the longest line of ``text`` [px] (sans-serif, 0.58 em a glyph)."""
    return max((len(line) for line in str(text).split("\n")), default=0) * 0.58 * size


def _blue(v: float) -> str:
    """The colour of ``v`` in [0, 1] on the Blues scale."""
    v = min(max(float(v), 0.0), 1.0)
    for (a, ca), (b, cb) in itertools.pairwise(_BLUES):
        if v <= b:
            f = (v - a) / (b - a)
            return "#" + "".join(f"{round(x + f * (y - x)):02x}"
                                 for x, y in zip(ca, cb, strict=True))
    return "#08306b"


def _nice_ticks(lo: float, hi: float, n: int = 6) -> list[float]:
    """About ``n`` round tick values within [lo, hi]."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo] if math.isfinite(lo) else []
    raw = (hi - lo) / max(n - 1, 1)
    mag = 10 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw)
    first = math.ceil(lo / step - 1e-9) * step
    return [round(first + k * step, 10) for k in range(int((hi - first) / step + 1e-9) + 1)]


def _tick_text(v: float) -> str:
    return f"{v:g}" if abs(v) >= 1e-9 else "0"


class _Svg:
    """An SVG drawing built as text."""

    def __init__(self, width: float, height: float) -> None:
        self.width, self.height = math.ceil(width), math.ceil(height)
        self.parts: list[str] = []

    def text(self, x: float, y: float, text: str, *, anchor: str = "start",
             size: float = FONT_PX, bold: bool = False, fill: str = "#222",
             rotate: float | None = None) -> None:
        """``text`` at (x, y) (the middle of its first line); lines split on newlines."""
        lines = str(text).split("\n")
        extra = f' transform="rotate({rotate:g} {x:.1f} {y:.1f})"' if rotate else ""
        weight = ' font-weight="bold"' if bold else ""
        spans = "".join(f'<tspan x="{x:.1f}" dy="{0 if k == 0 else _LINE}">'
                        f"{html.escape(line)}</tspan>" for k, line in enumerate(lines))
        self.parts.append(f'<text x="{x:.1f}" y="{y:.1f}" font-size="{size:g}" '
                          f'text-anchor="{anchor}" dominant-baseline="central" fill="{fill}"'
                          f"{weight}{extra}>{spans}</text>")

    def line(self, x1: float, y1: float, x2: float, y2: float, *, stroke: str = "#222",
             width: float = 1.0, dash: str | None = None) -> None:
        extra = f' stroke-dasharray="{dash}"' if dash else ""
        self.parts.append(f'<line x1="{x1:.1f}" y1="{y1:.1f}" x2="{x2:.1f}" y2="{y2:.1f}" '
                          f'stroke="{stroke}" stroke-width="{width:g}"{extra}/>')

    def rect(self, x: float, y: float, w: float, h: float, *, fill: str,
             stroke: str | None = None) -> None:
        extra = f' stroke="{stroke}"' if stroke else ""
        self.parts.append(f'<rect x="{x:.1f}" y="{y:.1f}" width="{max(w, 0):.1f}" '
                          f'height="{max(h, 0):.1f}" fill="{fill}"{extra}/>')

    def circle(self, x: float, y: float, r: float, *, fill: str) -> None:
        self.parts.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="{r:g}" fill="{fill}"/>')

    def named(self, name: str) -> tuple[str, str]:
        """(``name``, the drawing as an SVG document)."""
        return name, (
            f'<svg xmlns="http://www.w3.org/2000/svg" width="{self.width}" '
            f'height="{self.height}" viewBox="0 0 {self.width} {self.height}" '
            'font-family="DejaVu Sans, Helvetica, Arial, sans-serif">'
            f'<rect width="100%" height="100%" fill="white"/>{"".join(self.parts)}</svg>\n')


def _fit(lo, hi, *, floor: float | None = None, ceil: float | None = None
         ) -> tuple[float, float]:
    """x limits fitted to the intervals shown, with a margin; clipped to [floor, ceil]."""
    values = np.concatenate([np.asarray(lo, float), np.asarray(hi, float)])
    values = values[np.isfinite(values)]
    if not len(values):
        return (0.0, 1.0)
    a, b = float(values.min()), float(values.max())
    pad = max((b - a) * 0.08, 1e-3 if b == a else 0)
    a, b = a - pad, b + pad
    if floor is not None:
        a = max(a, floor)
    if ceil is not None:
        b = min(b, ceil)
    return (a, b) if b > a else (a - 0.5, a + 0.5)


def _panel(svg: _Svg, x0: float, y0: float, width: float, n_rows: int, row_h: float,
           series: list[dict], xlim: tuple[float, float], *, title: str = "",
           xlabel: str = "", vlines: tuple = (), band: tuple | None = None,
           grid: bool = True) -> None:
    """One dot-and-interval panel: ``series`` of dicts with ``est``, ``lo``, ``hi`` (n_rows,)
    and ``color``, ``offset`` (rows); rows top to bottom from ``y0`` (below the title)."""
    a, b = xlim
    height = n_rows * row_h

    def sx(v: float) -> float:
        return x0 + (min(max(v, a), b) - a) / (b - a) * width

    if title:
        for k, line in enumerate(title.split("\n")[::-1]):
            svg.text(x0, y0 - 8 - k * _LINE, line, size=FONT_PX + 1)
    svg.rect(x0, y0, width, height, fill="none", stroke="#999")
    for tick in _nice_ticks(a, b):
        x = sx(tick)
        if grid:
            svg.line(x, y0, x, y0 + height, stroke="#e5e5e5")
        svg.line(x, y0 + height, x, y0 + height + 4, stroke="#555")
        svg.text(x, y0 + height + 12, _tick_text(tick), anchor="middle")
    if xlabel:
        svg.text(x0 + width / 2, y0 + height + 30, xlabel, anchor="middle")
    if band is not None:
        for i, (lo, hi) in enumerate(zip(*band, strict=True)):
            if np.isfinite(lo) and np.isfinite(hi):
                y = y0 + (i + 0.5) * row_h
                svg.rect(sx(lo), y - 3.5, sx(hi) - sx(lo), 7, fill="#d9d9d9")
    for x, color, dash in vlines:
        if np.isfinite(x) and a <= x <= b:
            svg.line(sx(x), y0, sx(x), y0 + height, stroke=color, width=1, dash=dash)
    for s in series:
        for i, (est, lo, hi) in enumerate(zip(s["est"], s["lo"], s["hi"], strict=True)):
            y = y0 + (i + 0.5 + s.get("offset", 0.0)) * row_h
            if np.isfinite(lo) and np.isfinite(hi):
                lo_x, hi_x = sx(min(lo, est) if np.isfinite(est) else lo), sx(
                    max(hi, est) if np.isfinite(est) else hi)
                svg.line(lo_x, y, hi_x, y, stroke=s["color"], width=1.5)
                svg.line(lo_x, y - 3, lo_x, y + 3, stroke=s["color"], width=1.5)
                svg.line(hi_x, y - 3, hi_x, y + 3, stroke=s["color"], width=1.5)
            if np.isfinite(est):
                svg.circle(sx(est), y, 3.5, fill=s["color"])


def _row_labels(svg: _Svg, x: float, y0: float, names: list[str], row_h: float) -> None:
    for i, name in enumerate(names):
        lines = str(name).count("\n") + 1
        svg.text(x, y0 + (i + 0.5) * row_h - (lines - 1) * _LINE / 2, name, anchor="end")


def _legend(svg: _Svg, x: float, y: float, entries: list[tuple[str, str]],
            title: str = "") -> None:
    """A legend box with its top right corner at (x, y): (label, colour) entries."""
    width = max([_text_width(t) for t, _ in entries] + [_text_width(title)]) + 34
    rows = len(entries) + bool(title)
    svg.rect(x - width, y, width, rows * _LINE + 8, fill="white", stroke="#bbb")
    k = 0
    if title:
        svg.text(x - width + 8, y + 4 + _LINE / 2, title)
        k = 1
    for text, color in entries:
        yy = y + 4 + (k + 0.5) * _LINE
        if color.startswith("band:"):  # a grey band, as the forest plots draw it
            svg.rect(x - width + 8, yy - 3.5, 14, 7, fill=color[5:])
        else:
            svg.line(x - width + 8, yy, x - width + 22, yy, stroke=color, width=1.5)
            svg.circle(x - width + 15, yy, 3.5, fill=color)
        svg.text(x - width + 28, yy, text)
        k += 1


def _series(sub: pd.DataFrame, est: str, lo: str, hi: str, scale: float = 1.0, *,
            color: str = COLORS[0], offset: float = 0.0) -> dict:
    return {"est": (sub[est] * scale).to_numpy(float), "lo": (sub[lo] * scale).to_numpy(float),
            "hi": (sub[hi] * scale).to_numpy(float), "color": color, "offset": offset}


def _label_heatmap(counts: pd.DataFrame, env: str) -> tuple[str, str] | None:
    sub = counts[counts["env"] == env]
    if sub.empty:
        return None
    policies = sorted(sub["policy"].unique())
    top = sub.groupby("sdl")["share"].sum().sort_values(ascending=False).index[:TOP_LABELS]
    mat = (sub[sub["sdl"].isin(top)].pivot_table(index="sdl", columns="policy",
                                                 values="share", fill_value=0.0)
           .reindex(index=top, columns=policies, fill_value=0.0)).to_numpy()
    names = [_wrap(t, 52) for t in top]
    row_h = [max(name.count("\n") + 1, 1) * _LINE + 8 for name in names]
    left = max(_text_width(n) for n in names) + 14
    cell_w = 84.0
    top_y = 2 * _LINE + 10
    plot_h = float(sum(row_h))
    bottom = max(_text_width(p) for p in policies) * 0.55 + 24
    svg = _Svg(min(MAX_WIDTH_PX, left + cell_w * len(policies) + 90), top_y + plot_h + bottom)
    vmax = max(float(mat.max()), 0.05)  # the colour scale is fitted to the shares shown
    svg.text(4, _LINE, f"{env}: share of each policy's episodes with each ego label "
             f"(top {len(top)})", size=FONT_PX + 1)
    y = top_y
    for i, name in enumerate(names):
        svg.text(left - 8, y + row_h[i] / 2 - name.count("\n") * _LINE / 2, name,
                 anchor="end")
        for j in range(len(policies)):
            v = float(mat[i, j])
            x = left + j * cell_w
            svg.rect(x, y, cell_w, row_h[i], fill=_blue(v / vmax))
            if v > 0:
                svg.text(x + cell_w / 2, y + row_h[i] / 2, f"{v:.0%}", anchor="middle",
                         fill="white" if v > 0.6 * vmax else "black")
        y += row_h[i]
    for j, policy in enumerate(policies):
        x = left + (j + 0.5) * cell_w
        svg.text(x + 4, top_y + plot_h + 10, policy, anchor="end", rotate=-20)
    # the colour bar
    bar_x = left + cell_w * len(policies) + 12
    steps = 24
    for k in range(steps):
        svg.rect(bar_x, top_y + plot_h * (1 - (k + 1) / steps), 12, plot_h / steps + 0.5,
                 fill=_blue((k + 0.5) / steps))
    for tick in _nice_ticks(0.0, vmax, 4):
        yy = top_y + plot_h * (1 - tick / vmax)
        svg.line(bar_x + 12, yy, bar_x + 16, yy, stroke="#555")
        svg.text(bar_x + 18, yy, f"{tick:.0%}")
    return svg.named(f"labels_{_slug(env)}.svg")


def _measures_plot(scores: Scores, env: str, reference: str) -> tuple[str, str] | None:
    m = (scores.measures[scores.measures["env"] == env] if len(scores.measures) else
        scores.measures)
    if m.empty:
        return None
    policies = sorted(m["policy"].unique())
    row_h = 24.0
    left = max(_text_width(p) for p in policies) + 14
    gap = 24.0
    panel_w = (MAX_WIDTH_PX - left - gap * (len(MEASURES) - 1) - 10) / len(MEASURES)
    top_y = 2 * _LINE + 14
    svg = _Svg(MAX_WIDTH_PX, top_y + row_h * len(policies) + 26)
    _row_labels(svg, left - 8, top_y, policies, row_h)
    for k, meas in enumerate(MEASURES):
        sub = m[m["measure"] == meas.name].set_index("policy").reindex(policies)
        scale = meas.scale
        ref = sub.loc[reference, "mean"] * scale if reference in sub.index else np.nan
        low, high = meas.bounds if meas.bounds is not None else (None, None)
        xlim = _fit(sub["low"] * scale, sub["high"] * scale,
                    floor=None if low is None else low * scale,
                    ceil=None if high is None else high * scale)
        better = "higher" if meas.higher_is_better else "lower"
        _panel(svg, left + k * (panel_w + gap), top_y, panel_w, len(policies), row_h,
               [_series(sub, "mean", "low", "high", scale)], xlim,
               title=f"{meas.label} [{meas.display_unit}]\n{better} is better",
               vlines=((ref, "#999", "4 3"),))
    return svg.named(f"measures_{_slug(env)}.svg")


def _whole_labels(table: pd.DataFrame) -> pd.DataFrame:
    """The rows scored on whole labels (episodes or windows), not on segments (the
    coverage and novelty tables give both)."""
    if table.empty or "unit" not in table.columns:
        return table
    return table[~table["unit"].astype(str).str.endswith("segments")]


def _coverage_plot(coverage: pd.DataFrame) -> tuple[str, str] | None:
    """Coverage of each reference per policy, whole labels (``coverage``: the pooled rows
    of the coverage table)."""
    cov = _whole_labels(coverage)
    if cov.empty:
        return None
    refs = sorted(cov["reference"].unique())
    policies = sorted(cov["policy"].unique())
    row_h = 20.0 + 12.0 * len(refs)
    left = max(_text_width(p) for p in policies) + 14
    gap = 24.0
    legend_w = max(_text_width(r) for r in [*refs, "reference"]) + 50
    panel_w = (MAX_WIDTH_PX - left - gap - legend_w - 20) / 2
    top_y = _LINE + 14
    svg = _Svg(MAX_WIDTH_PX, top_y + row_h * len(policies) + 26)
    _row_labels(svg, left - 8, top_y, policies, row_h)
    panels = (("coverage", "coverage_low", "coverage_high",
               "coverage [%]: share of the reference's labels shown"),
              ("weighted_coverage", "weighted_low", "weighted_high",
               "frequency-weighted coverage [%]"))
    for p, (est, lo, hi, title) in enumerate(panels):
        series = []
        for k, ref in enumerate(refs):
            sub = cov[cov["reference"] == ref].set_index("policy").reindex(policies)
            series.append(_series(sub, est, lo, hi, 100.0, color=COLORS[k % len(COLORS)],
                                  offset=(k - (len(refs) - 1) / 2) * 0.25))
        _panel(svg, left + p * (panel_w + gap), top_y, panel_w, len(policies), row_h, series,
               _fit(cov[lo] * 100, cov[hi] * 100, floor=0, ceil=100), title=title)
    _legend(svg, MAX_WIDTH_PX - 14, top_y + 4,
            [(ref, COLORS[k % len(COLORS)]) for k, ref in enumerate(refs)], title="reference")
    return svg.named("coverage.svg")


def _forest_plots(scores: Scores, level: float) -> list[tuple[str, str]]:
    """Per pair of policies, one figure with a panel per env: the labels whose share of
    seeds differs most in that env, with their intervals and the simultaneous band."""
    labels = scores.paired_labels
    out: list[tuple[str, str]] = []
    if labels.empty:
        return out
    per_env = max(4, TOP_LABELS // 2)
    heading = interval_heading(level)
    for (a, b), pair in labels.groupby(["policy_a", "policy_b"], sort=True):
        envs = sorted(pair["env"].unique(), key=str)
        panels = []
        for env in envs:
            sub = pair[pair["env"] == env]
            sub = sub.reindex(sub["diff"].abs().sort_values(ascending=False).index)[:per_env]
            names = [_wrap(t, 60) for t in sub["label"]]
            lines = max((n.count("\n") + 1 for n in names), default=1)
            panels.append((env, sub, names, lines * _LINE + 9.0))
        xlim = _fit(pair["band_low"] * 100, pair["band_high"] * 100, floor=-100, ceil=100)
        left = max(_text_width(n) for _, _, names, _ in panels for n in names) + 14
        width = MAX_WIDTH_PX - left - 14
        legend = [("simultaneous band", "band:#d9d9d9"), (heading, COLORS[0])]
        title = f"{a} vs {b}, paired by seed: the labels that differ most, per env"
        svg_w = min(MAX_WIDTH_PX, max(left + width + 14, _text_width(title, FONT_PX + 1) + 8))
        top = _LINE + 8 + len(legend) * _LINE + 16  # the title, then the legend
        panel_gap = _LINE + 34  # tick labels of a panel and the next panel's title
        height = top + sum(len(sub) * row_h + panel_gap for _, sub, _, row_h in panels) + 30
        svg = _Svg(svg_w, height)
        svg.text(4, _LINE, title, size=FONT_PX + 1)
        _legend(svg, svg_w - 14, _LINE + 6, legend)
        y = top + _LINE
        for env, sub, names, row_h in panels:
            _row_labels(svg, left - 8, y, names, row_h)
            _panel(svg, left, y, width, len(sub), row_h,
                   [_series(sub, "diff", "diff_low", "diff_high", 100.0)], xlim, title=env,
                   band=((sub["band_low"] * 100).to_numpy(float),
                         (sub["band_high"] * 100).to_numpy(float)),
                   vlines=((0.0, "#000", None),))
            y += len(sub) * row_h + panel_gap
        svg.text(left + width / 2, y - panel_gap + 30,
                 f"difference in the share of seeds [percentage points]: {a} minus {b}",
                 anchor="middle")
        out.append(svg.named(f"forest_{_slug(a)}_vs_{_slug(b)}.svg"))
    return out


def _tradeoff_pairs(measures: pd.DataFrame) -> list[tuple[Measure, Measure]]:
    """(safety rate, progress measure) pairs the trade-off view draws: every registered
    measure of role ``safety`` that is a rate against every one of role ``progress``, in
    registration order, those the run scored (the crash rate against the mean speed built
    in; a user's progress measure adds its own row)."""
    scored = set(measures["measure"])
    rates = [m for m in measures_with_role("safety") if m.is_rate and m.name in scored]
    progress = [m for m in measures_with_role("progress") if m.name in scored]
    return [(r, p) for r in rates for p in progress]


def _tradeoff_plot(scores: Scores, reference: str) -> tuple[str, str] | None:
    """Safety against progress per env: each policy's safety rate (Wilson interval; the
    crash rate) against its progress (t interval; the mean speed), one row of panels per
    pair of measures whose entries have those roles (:func:`_tradeoff_pairs`); the
    reference's point marked (a square)."""
    m = scores.measures
    pairs = [] if m.empty else _tradeoff_pairs(m)
    if not pairs:
        return None
    envs = sorted((e for e in m["env"].unique() if e != "all"), key=str)
    if (m["env"] == "all").any() and len(envs) > 1:
        envs.append("all")
    policies = sorted(m["policy"].unique())
    colors = {p: COLORS[k % len(COLORS)] for k, p in enumerate(policies)}
    cols = min(3, len(envs))
    env_rows = -(-len(envs) // cols)
    rows = env_rows * len(pairs)
    legend_w = max(_text_width(p) for p in policies) + 34
    ylabel_w, tick_w, gap = _LINE + 8, 34.0, 22.0
    panel_w = ((MAX_WIDTH_PX - ylabel_w - legend_w - 24 - cols * tick_w - (cols - 1) * gap)
        / cols)
    panel_h, title_h, xlabel_h = 150.0, _LINE + 10, 2 * _LINE + 14
    svg = _Svg(MAX_WIDTH_PX, rows * (title_h + panel_h + xlabel_h) + 6)
    y_lo, y_hi = -3.0, 103.0
    for (safety, progress), (k, env) in itertools.product(pairs, enumerate(envs)):
        pair_row = pairs.index((safety, progress)) * env_rows
        r, c = divmod(k, cols)
        r += pair_row
        x0 = ylabel_w + tick_w + c * (panel_w + tick_w + gap)
        y0 = r * (title_h + panel_h + xlabel_h) + title_h
        sub = m[m["env"] == env]
        points = []
        for policy in policies:
            rate = sub[(sub["policy"] == policy) & (sub["measure"] == safety.name)]
            prog = sub[(sub["policy"] == policy) & (sub["measure"] == progress.name)]
            if rate.empty or prog.empty:
                continue
            points.append((policy, prog.iloc[0], rate.iloc[0]))
        xlim = _fit([s["low"] for _, s, _ in points] + [s["mean"] for _, s, _ in points],
                    [s["high"] for _, s, _ in points] + [s["mean"] for _, s, _ in points])

        def sx(v: float, xlim=xlim, x0=x0) -> float:
            return (x0 + (min(max(v, xlim[0]), xlim[1]) - xlim[0]) / (xlim[1] - xlim[0])
                * panel_w)

        def sy(v: float, y0=y0) -> float:
            return y0 + (y_hi - min(max(v, y_lo), y_hi)) / (y_hi - y_lo) * panel_h

        title = "pooled" if env == "all" else str(env)
        if len(pairs) > 1:
            title += f": {safety.label} / {progress.label}"
        svg.text(x0, y0 - title_h / 2 - 1, title, size=FONT_PX + 1)
        svg.rect(x0, y0, panel_w, panel_h, fill="none", stroke="#999")
        for tick in _nice_ticks(*xlim, n=5):
            svg.line(sx(tick), y0, sx(tick), y0 + panel_h, stroke="#e5e5e5")
            svg.line(sx(tick), y0 + panel_h, sx(tick), y0 + panel_h + 4, stroke="#555")
            svg.text(sx(tick), y0 + panel_h + 12, _tick_text(tick), anchor="middle")
        for tick in (0, 25, 50, 75, 100):
            svg.line(x0, sy(tick), x0 + panel_w, sy(tick), stroke="#e5e5e5")
            svg.line(x0 - 4, sy(tick), x0, sy(tick), stroke="#555")
            svg.text(x0 - 6, sy(tick), f"{tick}", anchor="end")
        for policy, prog, rate in points:
            color = colors[policy]
            x, y = float(prog["mean"]), float(rate["mean"]) * 100
            if not (np.isfinite(x) and np.isfinite(y)):
                continue
            for lo, hi in ((prog["low"], prog["high"]),):
                if np.isfinite(lo) and np.isfinite(hi):
                    svg.line(sx(min(lo, x)), sy(y), sx(max(hi, x)), sy(y), stroke=color,
                             width=1.5)
                    for v in (min(lo, x), max(hi, x)):
                        svg.line(sx(v), sy(y) - 3, sx(v), sy(y) + 3, stroke=color, width=1.5)
            lo, hi = float(rate["low"]) * 100, float(rate["high"]) * 100
            if np.isfinite(lo) and np.isfinite(hi):
                svg.line(sx(x), sy(min(lo, y)), sx(x), sy(max(hi, y)), stroke=color,
                         width=1.5)
                for v in (min(lo, y), max(hi, y)):
                    svg.line(sx(x) - 3, sy(v), sx(x) + 3, sy(v), stroke=color, width=1.5)
            if policy == reference:
                svg.rect(sx(x) - 4.5, sy(y) - 4.5, 9, 9, fill=color)
            else:
                svg.circle(sx(x), sy(y), 4.5, fill=color)
        if r == pair_row + env_rows - 1 or k + cols >= len(envs):
            svg.text(x0 + panel_w / 2, y0 + panel_h + 30,
                     f"{progress.label} [{progress.display_unit}] (progress)",
                     anchor="middle")
        if c == 0:
            better = "higher" if safety.higher_is_better else "lower"
            svg.text(_LINE / 2 + 2, y0 + panel_h / 2,
                     f"{safety.label} [%]\n({better} is safer)", anchor="middle", rotate=-90)
    _legend(svg, MAX_WIDTH_PX - 8, title_h,
            [(p + (" (reference, square)" if p == reference else ""), colors[p])
             for p in policies])
    return svg.named("tradeoff.svg")


def _improvement_plot(pm: pd.DataFrame) -> tuple[str, str] | None:
    """P(A better than B) per pair and measure (``pm``: the pooled rows of the paired
    measures)."""
    if pm.empty:
        return None
    pairs = pm[["policy_a", "policy_b"]].drop_duplicates().to_records(index=False)
    names, series = [], []
    for j, (a, b) in enumerate(pairs):
        sub = pm[(pm["policy_a"] == a) & (pm["policy_b"] == b)]
        est = np.full(len(pm), np.nan)
        lo, hi = est.copy(), est.copy()
        for r in sub.itertuples():
            k = len(names)
            est[k], lo[k], hi[k] = r.p_improvement, r.p_low, r.p_high
            meas = MEASURES.get(r.measure)
            names.append(f"{a} vs {b}: {meas.label if meas is not None else r.measure}")
        series.append({"est": est, "lo": lo, "hi": hi, "color": COLORS[j % len(COLORS)]})
    row_h = 22.0
    left = max(_text_width(n) for n in names) + 14
    top_y = 14.0
    svg = _Svg(950, top_y + row_h * len(names) + 44)
    _row_labels(svg, left - 8, top_y, names, row_h)
    _panel(svg, left, top_y, 950 - left - 14, len(names), row_h, series, (-0.02, 1.02),
           xlabel="P(A better than B on the same seed); ties count 1/2; 0.5: no difference",
           vlines=((0.5, "#000", None),), grid=False)
    return svg.named("improvement.svg")


def _novelty_plot(novelty: pd.DataFrame) -> tuple[str, str] | None:
    """The novelty rate against each reference per policy, whole labels (``novelty``: the
    pooled rows of the novelty table)."""
    nov = _whole_labels(novelty)
    if nov.empty:
        return None
    refs = sorted(nov["reference"].unique())
    policies = sorted(nov["policy"].unique())
    row_h = 20.0 + 12.0 * len(refs)
    left = max(_text_width(p) for p in policies) + 14
    top_y = 14.0
    legend_w = max(_text_width(r) for r in [*refs, "reference"]) + 50
    svg = _Svg(950, top_y + row_h * len(policies) + 44)
    _row_labels(svg, left - 8, top_y, policies, row_h)
    series = []
    for k, ref in enumerate(refs):
        sub = nov[nov["reference"] == ref].set_index("policy").reindex(policies)
        series.append(_series(sub, "novel_rate", "novel_low", "novel_high", 100.0,
                              color=COLORS[k % len(COLORS)],
                              offset=(k - (len(refs) - 1) / 2) * 0.25))
    _panel(svg, left, top_y, 950 - left - legend_w - 20, len(policies), row_h, series,
           _fit(nov["novel_low"] * 100, nov["novel_high"] * 100, floor=0, ceil=100),
           xlabel="novelty rate [%]: share of episodes whose ego label the reference "
           "never shows")
    _legend(svg, 946, top_y, [(ref, COLORS[k % len(COLORS)]) for k, ref in enumerate(refs)],
            title="reference")
    return svg.named("novelty.svg")


def draw_figures(scores: Scores, envs: list[str], reference: str, level: float
                 ) -> dict[str, bytes]:
    """Every figure of the report: file name -> SVG bytes, in report order (the names
    :func:`tap_bench.bench.report.page.write_plots` lists).

    Args:
        scores: the run's scores.
        envs: the envs of the scores (:attr:`~tap_bench.bench.scores.scoring.Scores.envs`):
            a label heat map and a measures plot each.
        reference: the reference policy ("" for none).
        level: the run's interval level, for the legends.
    """
    svgs: list[tuple[str, str] | None] = []
    # the pooled figures draw the rows of all envs (or of the one env)
    pm, cov, nov = (_pooled(t) for t in (scores.paired_measures, scores.coverage,
                                         scores.novelty))
    for env in envs:
        svgs.append(_label_heatmap(scores.label_counts, env))
        svgs.append(_measures_plot(scores, env, reference))
    if len(envs) > 1:
        svgs.append(_measures_plot(scores, "all", reference))
    svgs += [_tradeoff_plot(scores, reference), _improvement_plot(pm), _coverage_plot(cov),
             *_forest_plots(scores, level), _novelty_plot(nov)]
    return {name: text.encode() for name, text in (s for s in svgs if s is not None)}
