"""The run report's PNG figures, drawn at the size they are shown (text at least 10 px),
scales fitted to the data, labels whole: label heat maps, measures, coverage, forest plots,
improvement over the reference, novelty (part of :mod:`tap_bench.bench.report`)."""

from __future__ import annotations

import os
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd

from tap_bench.bench.measures import MEASURES
from tap_bench.bench.report_tables import (
    _envs,
    _pooled,
    _slug,
    interval_heading,
)
from tap_bench.bench.scoring import Scores

TOP_LABELS = 12  # labels shown per heat map and forest plot
DPI = 100  # figures are drawn at the size they are shown: 1 pt = 1.39 px
FONT_PT = 8.5  # smallest text in a figure: 11.8 px
MAX_WIDTH_IN = 11.0  # widest figure [in]: 1,100 px, inside the page's 1,200 px column


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    # names in figures are the user's text, never matplotlib math: a policy called
    # "a$b" or "$\\frac$" once crashed the report after the whole run
    plt.rcParams.update({"font.size": FONT_PT, "axes.titlesize": FONT_PT + 1,
                         "xtick.labelsize": FONT_PT, "ytick.labelsize": FONT_PT,
                         "legend.fontsize": FONT_PT, "text.parse_math": False})
    return plt


def _wrap(label: str, width: int = 48) -> str:
    """A label wrapped on whole words (never cut): ``A > B > C`` breaks after ``>``."""
    return "\n".join(textwrap.wrap(str(label), width=width, break_long_words=False,
                                   break_on_hyphens=False)) or str(label)


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=DPI)
    _plt().close(fig)
    return path


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
        k = meas.scale
        _interval_plot(ax, policies, sub["mean"] * k, sub["low"] * k, sub["high"] * k)
        ref = sub.loc[reference, "mean"] * k if reference in sub.index else np.nan
        if np.isfinite(ref):
            ax.axvline(ref, color="0.6", lw=0.8, ls="--")
        low, high = meas.bounds if meas.bounds is not None else (None, None)
        _fit(ax, sub["low"] * k, sub["high"] * k, floor=None if low is None else low * k,
             ceil=None if high is None else high * k)
        better = "higher" if meas.higher_is_better else "lower"
        ax.set_title(f"{meas.label} [{meas.display_unit}]\n{better} is better")
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


def _forest_plots(scores: Scores, folder: Path, level: float) -> list[Path]:
    """Per pair of policies, one figure with a panel per env: the labels whose share of
    seeds differs most in that env, with their intervals and the simultaneous band."""
    labels = scores.paired_labels
    out: list[Path] = []
    if labels.empty:
        return out
    plt = _plt()
    per_env = max(4, TOP_LABELS // 2)
    for (a, b), pair in labels.groupby(["policy_a", "policy_b"], sort=True):
        envs = sorted(pair["env"].unique(), key=str)
        panels = []
        for env in envs:
            sub = pair[pair["env"] == env]
            sub = sub.reindex(sub["diff"].abs().sort_values(ascending=False).index)[:per_env]
            panels.append((env, sub, [_wrap(t, 60) for t in sub["label"]]))
        heights = [1.0 + 0.2 * sum(n.count("\n") + 1 for n in names) + 0.1 * len(sub)
                   for _, sub, names in panels]
        fig, axes = plt.subplots(len(panels), 1, figsize=(MAX_WIDTH_IN, 0.6 + sum(heights)),
                                 layout="constrained", sharex=True,
                                 gridspec_kw={"height_ratios": heights}, squeeze=False)
        for ax, (env, sub, names) in zip(axes[:, 0], panels, strict=True):
            y = np.arange(len(sub))
            ax.hlines(y, sub["band_low"] * 100, sub["band_high"] * 100, color="0.85", lw=7,
                      label="simultaneous band")
            _interval_plot(ax, names, sub["diff"] * 100, sub["diff_low"] * 100,
                           sub["diff_high"] * 100, label=interval_heading(level))
            ax.axvline(0, color="k", lw=0.8)
            ax.invert_yaxis()
            ax.set_title(f"{env}", loc="left", fontsize="medium")
        _fit(axes[0, 0], pair["band_low"] * 100, pair["band_high"] * 100, floor=-100, ceil=100)
        axes[-1, 0].set_xlabel(f"difference in the share of seeds [percentage points]: {a} "
                               f"minus {b}")
        axes[0, 0].legend(loc="best", fontsize="small")
        fig.suptitle(f"{a} vs {b}, paired by seed: the labels that differ most, per env",
                     x=0.01, ha="left")
        out.append(_save(fig, folder / f"forest_{_slug(a)}_vs_{_slug(b)}.png"))
    return out


def _tradeoff_plot(scores: Scores, reference: str, folder: Path) -> Path | None:
    """Safety against progress per env: each policy's crash rate (Wilson interval) against
    its mean speed (t interval); the reference's point marked."""
    m = scores.measures
    if m.empty or not {"crashed", "mean_speed"} <= set(m["measure"]):
        return None
    plt = _plt()
    envs = sorted((e for e in m["env"].unique() if e != "all"), key=str)
    if (m["env"] == "all").any() and len(envs) > 1:
        envs.append("all")
    cols = min(3, len(envs))
    rows = -(-len(envs) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(MAX_WIDTH_IN, 2.6 * rows),
                             layout="constrained", squeeze=False)
    policies = sorted(m["policy"].unique())
    for ax, env in zip(axes.ravel(), envs, strict=False):
        sub = m[m["env"] == env]
        for k, policy in enumerate(policies):
            c = sub[(sub["policy"] == policy) & (sub["measure"] == "crashed")]
            v = sub[(sub["policy"] == policy) & (sub["measure"] == "mean_speed")]
            if c.empty or v.empty:
                continue
            c, v = c.iloc[0], v.iloc[0]
            xerr = np.nan_to_num([[max(v["mean"] - v["low"], 0)], [max(v["high"] - v["mean"],
                                                                       0)]])
            yerr = np.nan_to_num([[max(c["mean"] - c["low"], 0) * 100],
                                  [max(c["high"] - c["mean"], 0) * 100]])
            ax.errorbar(v["mean"], c["mean"] * 100, xerr=xerr, yerr=yerr, fmt="o" if
                        policy != reference else "s", color=f"C{k}", capsize=2, ms=5,
                        label=policy)
        ax.set_title("pooled" if env == "all" else env, loc="left", fontsize="medium")
        ax.set_ylim(-3, 103)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[len(envs):]:
        ax.axis("off")
    for ax in axes[:, 0]:
        ax.set_ylabel("crash rate [%] (lower is safer)")
    for ax in axes[-1, :]:
        ax.set_xlabel("mean speed [m/s] (progress)")
    handles, names = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, names, loc="outside right upper", fontsize="small")
    return _save(fig, folder / "tradeoff.png")


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
            meas = MEASURES.get(r.measure)
            name = meas.label if meas is not None else r.measure
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


def write_plots(scores: Scores, folder: str | os.PathLike, *,
                reference: str | None = None, level: float = 0.95) -> list[Path]:
    """Write the PNG plots of a scored run into ``folder`` and return their paths
    (``level``: the run's interval level, for the legends).

    Per env: ``labels_<env>.png`` (label heat map) and ``measures_<env>.png``; pooled:
    ``measures_all.png``, ``tradeoff.png`` (crash rate against mean speed, per env),
    ``improvement.png``, ``coverage.png``, ``forest_<A>_vs_<B>.png`` (a panel per env),
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
    paths += [_tradeoff_plot(scores, reference, folder), _improvement_plot(scores, folder),
              _coverage_plot(scores, folder),
              *_forest_plots(scores, folder, level), _novelty_plot(scores, folder)]
    return [p for p in paths if p is not None]
