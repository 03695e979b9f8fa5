"""Figures like the TAP paper's Figures 5 and 6, drawn from an :class:`Evaluation`, and
:func:`write_evaluation`, which writes an evaluation's tables, report and figures.

Figure 5: a reference trajectory (magenta), every trajectory with its exact SDL label (grey),
its nearest neighbours by ADE (dark blue) and by DTW (light blue), with their labels (a
neighbour's label in red when it differs from the reference's: extra actions marked ``+``,
missing ones ``-``), and the speeds on the right. Figure 6: unique trajectories with their
labels. All trajectories are normalised: they start at the origin heading along +x.
"""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np

from tap_bench import sdl
from tap_bench.similarity.evaluate import Evaluation, markdown
from tap_bench.tableio import atomic_path, write_table

__all__ = ["pick_examples", "similarity_figure", "unique_figure"]

REFERENCE = "#d6007e"  # magenta
ADE_COLOUR = "#08306b"  # dark blue
DTW_COLOUR = "#4fa3e0"  # light blue
MATCH_COLOUR = "#b0b0b0"
MAX_MATCHES_DRAWN = 60


def _tokens(text: str) -> tuple[list[str], list[str]]:
    lat, lon = sdl.parse_sdl(str(text))
    return list(lat), list(lon)


def _difference(reference: str, other: str) -> str:
    """'+extra, -missing' actions of ``other`` against ``reference`` (by set of tokens)."""
    ref = {t for side in _tokens(reference) for t in side}
    oth = {t for side in _tokens(other) for t in side}
    extra = [f"+{t}" for t in sorted(oth - ref)]
    missing = [f"-{t}" for t in sorted(ref - oth)]
    return ", ".join(extra + missing) or "same actions, other order"


def pick_examples(ev: Evaluation, n: int = 3) -> list[tuple[str, int]]:
    """Up to ``n`` (caption, query position) pairs in the spirit of Figure 5: both
    neighbours agree with SDL; both miss the behaviour; lateral right, longitudinal wrong.

    Among the queries meeting each condition, those with a turn and the most exact matches
    come first, so the grey SDL matches have something to show.
    """
    nb = ev.neighbours
    ls = ev.labels
    query = nb["query"].to_numpy()
    turning = ls.n_lateral[ls.code[query]] > 1
    # parked vehicles' jitter makes dull examples: prefer trajectories that travel 5 m
    extent = np.array([np.abs(ev.shapes[q]).max(initial=0.0) for q in query])
    score = nb["n_exact_matches"].to_numpy() + 1e6 * turning + 1e7 * (extent > 5.0)
    both_found = (nb["ade_neighbour"] >= 0).to_numpy() & (nb["dtw_neighbour"] >= 0).to_numpy()
    ade_d, dtw_d = nb["ade_different"].to_numpy(), nb["dtw_different"].to_numpy()
    lat_same = ~nb["ade_lateral_different"].to_numpy() & ~nb["dtw_lateral_different"].to_numpy()
    conditions = [
        ("ADE and DTW neighbours share the SDL label", ~ade_d & ~dtw_d),
        ("ADE and DTW neighbours miss the behaviour", ade_d & dtw_d),
        ("lateral matches, longitudinal differs", lat_same & (ade_d | dtw_d)),
    ]
    out: list[tuple[str, int]] = []
    for caption, mask in conditions[:n]:
        pos = np.flatnonzero(mask & both_found & (nb["n_exact_matches"].to_numpy() > 0))
        if len(pos) == 0:
            pos = np.flatnonzero(mask & both_found)
        pos = [p for p in pos if p not in {q for _, q in out}]
        if pos:
            out.append((caption, int(max(pos, key=lambda p: (score[p], -p)))))
    return out


def _wrap(text: str, width: int = 70) -> str:
    return "\n".join(textwrap.wrap(text, width=width, break_long_words=False))


def similarity_figure(ev: Evaluation, examples: list[tuple[str, int]] | None = None):
    """Figure 5: reference, SDL matches, ADE and DTW neighbours, speeds. None if no example."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    examples = pick_examples(ev) if examples is None else examples
    if not examples:
        return None
    shapes, ls, nb = ev.shapes, ev.labels, ev.neighbours
    fig, axes = plt.subplots(len(examples), 2, figsize=(13, 4.6 * len(examples)),
                             gridspec_kw={"width_ratios": [2.2, 1]}, squeeze=False)
    for row, (caption, pos) in enumerate(examples):
        ax, ax_v = axes[row]
        rec = nb.iloc[pos]
        ref = int(rec["query"])
        ref_text = str(ls.labels[ls.code[ref]])
        matches = np.flatnonzero(ls.code == ls.code[ref])
        matches = matches[matches != ref][:MAX_MATCHES_DRAWN]
        for k, m in enumerate(matches):
            pts = shapes[m]
            ax.plot(pts[:, 0], pts[:, 1], color=MATCH_COLOUR, lw=0.8, alpha=0.6, zorder=1,
                    label=f"same SDL label ({int(rec['n_exact_matches'])})" if k == 0 else None)
            ax_v.plot(shapes.time_of(m), shapes.speed_of(m), color=MATCH_COLOUR, lw=0.6,
                      alpha=0.4, zorder=1)
        differs = [False] * min(len(matches), 1)  # legend entries: matches, ADE, DTW, ref
        for metric, colour, name in (("ade", ADE_COLOUR, "ADE"), ("dtw", DTW_COLOUR, "DTW")):
            j = int(rec[f"{metric}_neighbour"])
            if j < 0:
                continue
            pts = shapes[j]
            text = str(ls.labels[ls.code[j]])
            note = "" if text == ref_text else f"  [{_difference(ref_text, text)}]"
            differs.append(bool(note))
            ax.plot(pts[:, 0], pts[:, 1], color=colour, lw=3.6 if metric == "ade" else 1.8,
                    zorder=3,
                    label=_wrap(f"nearest by {name} ({rec[f'{metric}_distance']:.2f} m): "
                                f"{text}{note}", 110))
            ax_v.plot(shapes.time_of(j), shapes.speed_of(j), color=colour, lw=1.8, zorder=3)
        pts = shapes[ref]
        ax.plot(pts[:, 0], pts[:, 1], color=REFERENCE, lw=2.6, zorder=4,
                label=_wrap(f"reference: {ref_text}", 110))
        differs.append(False)
        ax.plot(0, 0, "o", color="black", ms=4, zorder=5)
        ax_v.plot(shapes.time_of(ref), shapes.speed_of(ref), color=REFERENCE, lw=2.4, zorder=4)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x along the initial heading [m]")
        ax.set_ylabel("y, left [m]")
        ax.set_title(f"{row + 1}. {caption}: {rec['scenario_id']}:{rec['track_id']}",
                     fontsize=10, loc="left")
        legend = ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.2), fontsize=8,
                           frameon=False)
        for entry, red in zip(legend.get_texts(), differs, strict=False):
            if red:
                entry.set_color("red")
        ax_v.set_xlabel("t [s]")
        ax_v.set_ylabel("speed [m/s]")
        ax_v.grid(alpha=0.3)
    fig.tight_layout(h_pad=2.0)
    return fig


def unique_figure(ev: Evaluation, n: int = 2):
    """Figure 6: the ``n`` unique trajectories with the most actions. None if none."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    ls = ev.labels
    rows = np.flatnonzero(ls.counts[ls.code] == 1)
    if len(rows) == 0:
        return None
    actions = ls.n_lateral[ls.code[rows]] + ls.n_longitudinal[ls.code[rows]]
    rows = rows[np.argsort(-actions, kind="stable")][:n]
    fig, axes = plt.subplots(2, len(rows), figsize=(6.5 * len(rows), 8),
                             gridspec_kw={"height_ratios": [2, 1]}, squeeze=False)
    for k, r in enumerate(rows):
        ax, ax_v = axes[0, k], axes[1, k]
        pts = ev.shapes[r]
        ax.plot(pts[:, 0], pts[:, 1], color=REFERENCE, lw=2.4)
        ax.plot(0, 0, "o", color="black", ms=4)
        ax.set_aspect("equal", adjustable="datalim")
        lat, lon = _tokens(str(ls.labels[ls.code[r]]))
        key = ls.table.iloc[r]
        ax.set_title(f"{key['scenario_id']}:{key['track_id']}: {len(lat)} lateral, "
                     f"{len(lon)} longitudinal actions\n"
                     + _wrap(sdl.join(lat), 60) + "\n"
                     + _wrap(sdl.join(lon), 60), fontsize=8)
        ax.set_xlabel("x along the initial heading [m]")
        ax.set_ylabel("y, left [m]")
        ax_v.plot(ev.shapes.time_of(r), ev.shapes.speed_of(r), color=REFERENCE, lw=2)
        ax_v.set_xlabel("t [s]")
        ax_v.set_ylabel("speed [m/s]")
        ax_v.grid(alpha=0.3)
    fig.suptitle("Trajectories whose SDL label no other trajectory has", fontsize=11)
    fig.tight_layout()
    return fig


def write_evaluation(ev: Evaluation, out_dir: str | Path, *, figures: bool = True) -> list[Path]:
    """Write evaluation.json, evaluation.md, neighbours.parquet, unique.parquet and the PNG
    figures into ``out_dir``, each atomically. Returns the paths written."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    path = out / "evaluation.json"
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(ev.summary, indent=2, default=_json_default))
    written.append(path)
    path = out / "evaluation.md"
    with atomic_path(path) as tmp:
        tmp.write_text(markdown(ev))
    written.append(path)
    written.append(write_table(ev.neighbours, out / "neighbours.parquet"))
    written.append(write_table(ev.unique, out / "unique.parquet"))
    if figures:
        for name, make in (("fig5_similarity.png", similarity_figure),
                           ("fig6_unique.png", unique_figure)):
            fig = make(ev)
            if fig is None:
                continue
            path = out / name
            with atomic_path(path) as tmp:
                fig.savefig(tmp, format="png", dpi=120, bbox_inches="tight")
            import matplotlib.pyplot as plt

            plt.close(fig)
            written.append(path)
    return written


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot write {type(value).__name__} as JSON")

