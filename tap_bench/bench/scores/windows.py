"""Episodes cut in windows of a reference's track length: a 30 s episode held against
WOMD's 9.1 s tracks is scored as its consecutive 9.1 s windows, so that coverage and
novelty compare behaviour over the same span of time on both sides.

- :func:`window_seconds`: the window length a choice gives (``auto``: the reference's
  median track length, :func:`track_seconds`, when the episodes are longer);
- :func:`windows`: a trajectory table cut into windows, each its own scenario
  ``<scenario_id>#<k>``; :func:`number_windows` numbers them as seeds;
- :func:`window_episodes`: the egos' windows labelled, as an episode table;
- :func:`window_episode`: the episode each window was cut from, the cluster a bootstrap
  resamples whole (the windows of one episode are not independent); the episode table of
  windows carries it as its :data:`CUT_FROM` column, which the coverage, the novelty and
  the same-policy null read.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from tap_bench.errors import ParameterError
from tap_bench.labelling import tap
from tap_bench.thresholds import Thresholds

__all__ = ["CUT_FROM", "number_windows", "track_seconds", "window_episode",
           "window_episodes", "window_seconds", "windows"]

CUT_FROM = "cut_from"
"""The column of an episode table of windows naming the episode (``scenario_id``) each
window was cut from (:func:`window_episode`)."""


def track_seconds(table: pd.DataFrame) -> float:
    """The median duration [s] of a trajectory table's tracks (WOMD: 9.1 s)."""
    t = table.groupby(["scenario_id", "track_id"], sort=False)["t"]
    return float((t.max() - t.min()).median())


def windows(table: pd.DataFrame, seconds: float) -> pd.DataFrame:
    """A trajectory table cut into consecutive windows of ``seconds`` per scenario (a
    30 s episode against 9.1 s WOMD tracks: three windows, the rest dropped when shorter
    than half a window). Each window is its own scenario, ``<scenario_id>#<k>``; ``t``
    keeps its values.

    Raises:
        ValueError: ``seconds`` not a positive number.
    """
    if not np.isfinite(seconds) or seconds <= 0:
        raise ValueError(f"window length must be a positive number of seconds, got "
                         f"{seconds!r}.")
    t0 = table.groupby("scenario_id", sort=False)["t"].transform("min")
    k = np.floor((table["t"] - t0 + 1e-9) / seconds).astype(int)
    ends = (table.assign(_k=k).groupby(["scenario_id", "_k"], sort=False)["t"]
            .transform(lambda t: t.max() - t.min()))
    keep = (ends >= seconds / 2 - 1e-9).to_numpy()
    out = table[keep].copy()
    out["scenario_id"] = out["scenario_id"].astype(str) + "#" + k[keep].astype(str)
    return out


def window_episode(scenario_ids) -> np.ndarray:
    """(n,) the episode each window of :func:`windows` was cut from: its ``scenario_id``
    without the ``#<k>`` suffix (the cluster whose windows are resampled together)."""
    return np.asarray(pd.Series(np.asarray(scenario_ids, dtype=object)).astype(str)
                      .str.replace(r"#\d+$", "", regex=True), dtype=object)


def window_seconds(choice: str, reference: pd.DataFrame, table: pd.DataFrame) -> float | None:
    """The window length [s] a ``--window`` choice gives: None for ``"none"``; for
    ``"auto"`` the reference's median track length (:func:`track_seconds`) when ``table``'s
    tracks are longer (None when they are not, or when either table has no times, e.g. a
    label table); else a number of seconds > 0.

    Raises:
        ParameterError: the choice is none of these.
    """
    if choice == "none":
        return None
    if choice == "auto":
        if "t" not in reference.columns or "t" not in table.columns:
            return None
        seconds = track_seconds(reference)
        # tracks no longer than the reference's: windows would change nothing
        return seconds if track_seconds(table) > 1.05 * seconds else None
    try:
        seconds = float(choice)
    except ValueError:
        seconds = float("nan")
    if not seconds > 0:
        raise ParameterError("--window", choice, "'auto', 'none' or a number of seconds > 0")
    return seconds


def number_windows(table: pd.DataFrame) -> pd.DataFrame:
    """A windowed table (:func:`windows`) whose ``seed`` numbers the windows (0, 1, ... in
    order of appearance) and whose ``episode_seed`` keeps the episode's seed: one seed is
    one episode in the episode table, and windows are not paired with other policies'."""
    out = table.copy()
    if "seed" in out.columns:
        out["episode_seed"] = out["seed"]
    out["seed"] = pd.factorize(out["scenario_id"])[0]
    return out


def window_episodes(trajectories: pd.DataFrame, seconds: float, level: str, *,
                    thresholds: str | Thresholds = "paper", source: str = "trajectories"
                    ) -> pd.DataFrame:
    """The episode table (:mod:`tap_bench.bench.episodes`) of the egos' :func:`windows`:
    one row per window (``scenario_id`` ``<episode>#<k>``, the episode's env and policy,
    ``seed`` numbering the windows: :func:`number_windows`, :data:`CUT_FROM` the episode
    it was cut from), labelled at ``level``; measures NaN. Coverage and novelty against a
    corpus of short tracks (WOMD: 9.1 s) score these in place of whole 30 s episodes."""
    from tap_bench.bench.episodes import episode_table

    ego = (trajectories[trajectories["is_ego"].fillna(False).to_numpy(bool)]
        if "is_ego" in trajectories.columns else trajectories)
    cut = number_windows(windows(ego, seconds))
    labels = tap(cut, thresholds, source=source).labels("all")
    table = episode_table(labels=labels, level=level, source=source)
    return table.assign(**{CUT_FROM: window_episode(table["scenario_id"])})
