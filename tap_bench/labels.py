"""The label table and the segment table: their contract (SPEC section 1), checked once.

The twin of :mod:`tap_bench.trajectories` for TAP's output. Every module that reads a label
table (search, uniqueness, coverage, comparison, the benchmark) goes through
:func:`validate_labels`, which checks the columns and the SDL text and selects one level.

**Label table**, one row per trajectory (valid segment of a track) and level:

==============  ===========================================================================
scenario_id     str
track_id        str
segment         int, the valid segment of the track (0, 1, ...)
level           ``trace``, ``trend``, ``maneuver`` or ``action``
lateral         the lateral labels in order, joined by ``" > "``
longitudinal    the longitudinal labels in order, joined by ``" > "``
sdl             ``lateral + " | " + longitudinal`` (built by :func:`tap_bench.sdl.format_sdl`)
t_start, t_end  the segment's first and last time [s]
==============  ===========================================================================

then, from :func:`tap_bench.tap`, the glitch counts of the segment (:data:`GLITCH_COLUMNS`,
SPEC section 2), followed by the identifying columns the trajectory table had (``source``, ``env``,
``policy``, ``seed``, ``is_ego`` ...). **Segment table**: one row per label run,
:data:`SEGMENT_COLUMNS`, ``axis`` naming the axis of ``label``.

**Interactions** (SPEC 7, :mod:`tap_bench.interactions`): a table labelled with interactions
has an ``interaction`` column in the label table (the relations joined by ``" > "``; NA on
tracks not labelled on that axis), and ``axis = "interaction"`` rows in the segment table
with an ``other_track_id`` column (the other agent; NA on the other axes and on Free
Driving). :func:`label_text` gives a row's label on any choice of axes.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc

from tap_bench import sdl
from tap_bench.errors import LabelTableError

__all__ = ["GLITCH_COLUMNS", "LABEL_COLUMNS", "REQUIRED_LABEL_COLUMNS", "SEGMENT_COLUMNS",
           "label_text", "missing_axes", "row_key", "select_level", "validate_labels"]

LABEL_COLUMNS = ("scenario_id", "track_id", "segment", "level", "lateral", "longitudinal",
                 "sdl", "t_start", "t_end")
"""Columns of the label table, followed by the identifying columns the input had."""
GLITCH_COLUMNS = ("heading_glitches", "speed_glitches", "reversing_steps", "travel")
"""Per labelled segment, after ``t_end``: steps whose heading change was a flip or faster than
the vehicle can turn, steps whose speed was a spike, steps moving against the heading
(:mod:`tap_bench.kinematics`), and how far the segment gets from its start [m] (under 1 m:
no turn, no merge)."""
SEGMENT_COLUMNS = ("scenario_id", "track_id", "segment", "level", "axis", "label", "t_start",
                   "t_end")
"""Columns of the segment table, followed by the identifying columns the input had."""
REQUIRED_LABEL_COLUMNS = ("scenario_id", "track_id", "lateral", "longitudinal", "sdl")
"""What a label table must have to be read (``level`` may be missing for one-level tables)."""


def row_key(table: pd.DataFrame, pos: int) -> str:
    """``scenario_id=..., track_id=..., segment=...`` of row ``pos``, for messages."""
    parts = [f"{c}={table[c].iloc[pos]!r}" for c in ("scenario_id", "track_id", "segment")
             if c in table.columns]
    return ", ".join(parts)


def select_level(labels: pd.DataFrame, level: str | None, source: str = "label table"
                 ) -> tuple[pd.DataFrame, str | None]:
    """The rows of one level, and that level.

    Args:
        labels: a label table.
        level: the level to keep; None when the table holds a single level (or no ``level``
            column, for which None stays None).
        source: the table's name in messages (its path).

    Raises:
        LabelTableError: several levels and none chosen, or the level asked for is absent.
        UnknownNameError: ``level`` is not an SDL level.
    """
    if level is not None:
        sdl.check_level(level)
    if "level" not in labels.columns:
        return labels, level
    present = [lv for lv in sdl.LEVELS if lv in set(labels["level"].astype(str).unique())]
    if level is None:
        if len(present) != 1:
            raise LabelTableError(
                f"{source}: the table holds labels of {len(present)} levels "
                f"({', '.join(present)}); choose one with level=... (--level).")
        level = present[0]
    elif level not in present:
        raise LabelTableError(f"{source}: no labels at level {level!r}; the table has "
                              f"{', '.join(present) or 'none'}. Label at that level with "
                              f"'tap-bench label --level {level}' (or --level all).")
    rows = (labels["level"].astype(str) == level).to_numpy()
    return labels.loc[rows], level


def validate_labels(labels: pd.DataFrame, level: str | None = None, *,
                    source: str = "label table", axes=None
                    ) -> tuple[pd.DataFrame, str | None, np.ndarray]:
    """Check a label table and select one level: the one label validator of tap-bench.

    On TAP's two axes (the default) it checks the required columns, that no label is empty
    and that ``sdl`` is ``lateral | longitudinal`` on every row (one vectorised pass). On
    other ``axes`` (with ``interaction``) it checks their columns and that no kept row has
    an empty label; rows of tracks not labelled with interactions are left out. The SDL
    tokens are checked against the level's vocabulary by whoever parses them
    (:func:`tap_bench.sdl.parse_sdl`, once per distinct label).

    Args:
        labels: a label table (SPEC section 1).
        level: the level to keep (see :func:`select_level`).
        source: the table's name in messages (its path).
        axes: the label axes to check (:func:`tap_bench.sdl.check_axes`; default TAP's).

    Returns:
        (the level's rows with the index reset, the level, (n,) the rows' positions in the
        input, for messages).

    Raises:
        LabelTableError: naming the column, the row (position in the input, with scenario,
            track and segment) and the fix.
    """
    if not isinstance(labels, pd.DataFrame):
        raise LabelTableError(f"{source}: expected a label table (pandas DataFrame), got "
                              f"{type(labels).__name__}.")
    axes = sdl.check_axes(axes)
    if axes != sdl.AXES:
        return _on_axes(labels, level, axes, source)
    missing = [c for c in REQUIRED_LABEL_COLUMNS if c not in labels.columns]
    if missing:
        raise LabelTableError(
            f"{source}: missing column(s) {', '.join(map(repr, missing))}; a label table has "
            f"{', '.join(REQUIRED_LABEL_COLUMNS)} (and level, t_start, t_end): make it with "
            "'tap-bench label'.")
    table, level = select_level(labels, level, source)
    if len(table) == 0:
        raise LabelTableError(f"{source}: the label table is empty.")
    table = table.reset_index(drop=True)
    input_rows = (np.flatnonzero(labels["level"].astype(str).to_numpy() == level)
        if "level" in labels.columns else np.arange(len(labels)))
    for col in ("lateral", "longitudinal", "sdl"):
        empty = table[col].isna().to_numpy()
        if empty.any():
            pos = int(np.flatnonzero(empty)[0])
            raise LabelTableError(f"{source}: column {col!r} is empty at row "
                                  f"{int(input_rows[pos])} ({row_key(table, pos)}); every row "
                                  "needs a label.")

    def arrow(col: str) -> pa.Array:
        return pa.array(table[col].astype(str), type=pa.large_string())

    joined = pc.binary_join_element_wise(arrow("lateral"), arrow("longitudinal"),
                                         pa.scalar(sdl.SDL_SEPARATOR, pa.large_string()))
    bad = ~np.asarray(pc.equal(joined, arrow("sdl")), dtype=bool)
    if bad.any():
        pos = int(np.flatnonzero(bad)[0])
        raise LabelTableError(
            f"{source}: row {int(input_rows[pos])} ({row_key(table, pos)}): sdl "
            f"{table['sdl'].iloc[pos]!r} is not lateral + {sdl.SDL_SEPARATOR!r} + longitudinal "
            f"({table['lateral'].iloc[pos]!r}, {table['longitudinal'].iloc[pos]!r}). Rebuild "
            "the table with 'tap-bench label'.")
    return table, level, input_rows


def _on_axes(labels: pd.DataFrame, level: str | None, axes: tuple[str, ...],
             source: str) -> tuple[pd.DataFrame, str | None, np.ndarray]:
    """:func:`validate_labels` on axes other than TAP's two: the rows of one level that
    carry a label on every axis (tracks not labelled with interactions are left out)."""
    missing = [c for c in ("scenario_id", "track_id", *axes) if c not in labels.columns]
    if missing:
        raise LabelTableError(f"{source}: {missing_axes(missing)}")
    table, level = select_level(labels, level, source)
    input_rows = (np.flatnonzero(labels["level"].astype(str).to_numpy() == level)
        if "level" in labels.columns else np.arange(len(labels)))
    if "interaction" in axes:
        on_axis = table["interaction"].notna().to_numpy()
        if not on_axis.any():
            raise LabelTableError(f"{source}: no row carries an interaction label; label the "
                                  "table with --interactions (or --interactions all).")
        table, input_rows = table.loc[on_axis], input_rows[on_axis]
    if len(table) == 0:
        raise LabelTableError(f"{source}: the label table is empty.")
    table = table.reset_index(drop=True)
    for col in axes:
        empty = table[col].isna().to_numpy()
        if empty.any():
            pos = int(np.flatnonzero(empty)[0])
            raise LabelTableError(f"{source}: column {col!r} is empty at row "
                                  f"{int(input_rows[pos])} ({row_key(table, pos)}); every row "
                                  "needs a label.")
    return table, level, input_rows


def label_text(labels: pd.DataFrame, axes=None) -> pd.Series:
    """The label of each row on ``axes`` (:func:`tap_bench.sdl.check_axes`): its sequences
    joined by ``" | "`` in the order of :data:`tap_bench.sdl.LABEL_AXES` (``sdl`` for TAP's
    two axes); NA where an axis is empty (a track not labelled on that axis).

    Raises:
        LabelTableError: a column of the axes is missing (with how to label it).
    """
    axes = sdl.check_axes(axes)
    if axes == sdl.AXES and "sdl" in labels.columns:
        return labels["sdl"]
    missing = [a for a in axes if a not in labels.columns]
    if missing:
        raise LabelTableError(missing_axes(missing))
    arrays = [pa.array(labels[a].astype("string"), type=pa.large_string()) for a in axes]
    joined = arrays[0] if len(arrays) == 1 else pc.binary_join_element_wise(
        *arrays, pa.scalar(sdl.SDL_SEPARATOR, pa.large_string()))
    return pd.Series(joined.to_pandas(), index=labels.index, dtype="string")


def missing_axes(missing: list[str]) -> str:
    """The message for label columns of chosen axes that a table lacks."""
    fix = (" Label with 'tap-bench label --interactions' (tap(..., interactions='auto'))."
           if "interaction" in missing else " Make the table with 'tap-bench label'.")
    return f"no {', '.join(map(repr, missing))} column for the axes asked for.{fix}"
