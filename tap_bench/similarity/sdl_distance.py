"""Distances between SDL labels: exact (g_SDL) and Levenshtein over label tokens.

Labels are compared on chosen axes (``axes=``): TAP's lateral and longitudinal by default,
the interaction axis of SPEC 7 beside or instead of them.

An SDL label ``"Straight > Gradual Left Turn > Straight | Maintain Medium Speed"`` is two
token sequences: lateral (``Straight``, ``Gradual Left Turn``, ``Straight``) and longitudinal
(``Maintain Medium Speed``). The distances here (SPEC section 5, TAP paper section 6.3):

- ``g_SDL(a, b)``: 0 when the labels are equal, 1 otherwise;
- Levenshtein: the edit distance over lateral tokens plus the edit distance over
  longitudinal tokens (insert, delete or substitute one whole label, cost 1 each), computed
  by rapidfuzz's C++ edit-distance kernels.

:class:`LabelSet` encodes one level of a label table once (each distinct token sequence as a
short string of one character per token) so that whole data sets compare in milliseconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
from rapidfuzz.distance import Levenshtein
from rapidfuzz.process import cdist

from tap_bench import sdl
from tap_bench.errors import LabelTableError, did_you_mean

__all__ = [
    "METRICS",
    "LabelSet",
    "g_sdl",
    "label_set",
    "label_text",
    "levenshtein_matrix",
    "parse_sdl",
    "sdl_levenshtein",
]

METRICS = ("exact", "levenshtein")
"""Label distances: ``exact`` is g_SDL (0 or 1), ``levenshtein`` the token edit distance."""

REQUIRED_LABEL_COLUMNS = ("scenario_id", "track_id", "lateral", "longitudinal", "sdl")

# Every token of each axis over all levels; one character per token in the encoded strings.
_TOKENS = {
    axis: tuple(dict.fromkeys(name for level in sdl.LEVELS for name in sdl.vocabulary(level, axis)))
    for axis in sdl.LABEL_AXES
}
_CHAR = {axis: {tok: chr(0x41 + i) for i, tok in enumerate(toks)} for axis, toks in _TOKENS.items()}


def parse_sdl(text: str, *, level: str | None = None, axes=None) -> tuple[tuple[str, ...], ...]:
    """Split a label into its token sequences, one per axis.

    Args:
        text: ``"<lateral> > <lateral> ... | <longitudinal> > ..."`` (the SDL label), or with
            other ``axes`` their sequences joined by ``" | "`` in the order of
            :data:`tap_bench.sdl.LABEL_AXES` (e.g. ``"Straight | Following > Cut-in"``).
        level: when given, every token must belong to that level's vocabulary.
        axes: the axes the label holds (default: lateral and longitudinal).

    Returns:
        one tuple of tokens per axis, each in chronological order.

    Raises:
        LabelTableError: not one ``" | "`` between consecutive axes, an empty side, or an
            unknown token (with the closest known tokens).
    """
    axes = sdl.check_axes(axes)
    bar = sdl.SDL_SEPARATOR.strip()
    if not isinstance(text, str) or text.count(bar) != len(axes) - 1:
        example = ("'Straight > Gradual Left Turn" + sdl.SDL_SEPARATOR + "Maintain Medium Speed'"
                   if axes == sdl.AXES else "one sequence per axis")
        raise LabelTableError(
            f"label {text!r} must hold {len(axes)} sequence(s) ({', '.join(axes)}) joined by "
            f"{sdl.SDL_SEPARATOR!r}, e.g. {example}.")
    return tuple(_tokens(part, axis, level, text)
                 for part, axis in zip(text.split(bar), axes, strict=True))


def _tokens(seq: str, axis: str, level: str | None, where: str) -> tuple[str, ...]:
    tokens = tuple(tok.strip() for tok in seq.split(sdl.SEPARATOR.strip()))
    known = sdl.vocabulary(level, axis) if level else _TOKENS[axis]
    for tok in tokens:
        if not tok:
            raise LabelTableError(f"SDL label {where!r}: an empty {axis} label; labels are "
                                  f"joined by {sdl.SEPARATOR!r} with one on each side.")
        if tok not in known:
            scope = f"{level}-level {axis} label" if level else f"{axis} label"
            raise LabelTableError(f"SDL label {where!r}: {did_you_mean(scope, tok, known)}")
    return tokens


def g_sdl(a: str, b: str) -> int:
    """The paper's g_SDL: 0 when the two SDL labels are equal, 1 otherwise."""
    return int(a != b)


def sdl_levenshtein(a: str, b: str, *, axes=None) -> int:
    """Levenshtein distance between two labels over whole label tokens.

    The sum over the axes of each axis's edit distance; each insertion, deletion or
    substitution of one label costs 1. ``"Straight | Maintain Medium Speed"`` against
    ``"Straight > Gradual Left Turn > Straight | Maintain Medium Speed"`` is 2.
    """
    return int(sum(Levenshtein.distance(x, y) for x, y in zip(
        parse_sdl(a, axes=axes), parse_sdl(b, axes=axes), strict=True)))


def _encode(tokens: tuple[str, ...] | list[str], axis: str) -> str:
    return "".join(_CHAR[axis][tok] for tok in tokens)


@dataclass(frozen=True)
class LabelSet:
    """One level of a label table on chosen axes, encoded for fast comparison.

    Rows are the label table's rows at that level, in their input order; a row is one
    trajectory (one valid segment of a track). A row's label is its sequences on ``axes``
    joined by ``" | "``: the SDL label for TAP's two axes.

    Attributes:
        table: (n rows) the label rows at ``level``, index reset.
        level: the SDL level (``trace`` ... ``action``), or None when the table has no
            ``level`` column.
        axes: the axes compared (:data:`tap_bench.sdl.LABEL_AXES`, in that order).
        code: (n,) int64, index of each row's label in ``labels``.
        labels: (u,) the distinct labels (object array of str), in order of first use.
        counts: (u,) int64, rows holding each distinct label.
        first_row: (u,) int64, the first row holding each label.
        axis_index: (u, k) int64, index of each label's sequence on axis j in
            ``axis_strings[j]``.
        axis_strings: per axis, its distinct sequences, one character per token.
        n_tokens: (u, k) int64 tokens of each label on each axis.
    """

    table: pd.DataFrame
    level: str | None
    axes: tuple[str, ...]
    code: np.ndarray
    labels: np.ndarray
    counts: np.ndarray
    first_row: np.ndarray
    axis_index: np.ndarray
    axis_strings: tuple[list[str], ...]
    n_tokens: np.ndarray

    def __len__(self) -> int:
        return len(self.code)

    @property
    def n_labels(self) -> int:
        return len(self.labels)

    def _axis(self, axis: str) -> int:
        if axis not in self.axes:
            raise LabelTableError(f"this label set compares {', '.join(self.axes)}; it has no "
                                  f"{axis} axis.")
        return self.axes.index(axis)

    @property
    def lateral(self) -> np.ndarray:
        return self.axis_index[:, self._axis("lateral")]

    @property
    def longitudinal(self) -> np.ndarray:
        return self.axis_index[:, self._axis("longitudinal")]

    @property
    def lateral_strings(self) -> list[str]:
        return self.axis_strings[self._axis("lateral")]

    @property
    def longitudinal_strings(self) -> list[str]:
        return self.axis_strings[self._axis("longitudinal")]

    def n_on(self, axis: str) -> np.ndarray:
        """(u,) tokens of each label on ``axis`` (0 when the set does not compare it)."""
        if axis not in self.axes:
            return np.zeros(self.n_labels, np.int64)
        return self.n_tokens[:, self.axes.index(axis)]

    @property
    def n_lateral(self) -> np.ndarray:
        return self.n_on("lateral")

    @property
    def n_longitudinal(self) -> np.ndarray:
        return self.n_on("longitudinal")

    def encode(self, text: str) -> tuple[str, ...]:
        """A label as one encoded string per axis, checked at this level."""
        return tuple(_encode(tok, axis) for tok, axis in zip(
            parse_sdl(text, level=self.level, axes=self.axes), self.axes, strict=True))

    def levenshtein_to(self, text: str) -> np.ndarray:
        """(u,) int32 Levenshtein distance from ``text`` to each distinct label."""
        out = np.zeros(self.n_labels, np.int32)
        for j, enc in enumerate(self.encode(text)):
            d = cdist([enc], self.axis_strings[j], scorer=Levenshtein.distance,
                      dtype=np.int32)[0]
            out += d[self.axis_index[:, j]]
        return out


def _select_level(labels: pd.DataFrame, level: str | None, source: str) -> tuple[pd.DataFrame,
                                                                                 str | None]:
    if "level" not in labels.columns:
        if level is not None and level not in sdl.LEVELS:
            raise did_you_mean("level", level, sdl.LEVELS)
        return labels, level
    present = [lv for lv in sdl.LEVELS if lv in set(labels["level"].astype(str).unique())]
    if level is None:
        if len(present) != 1:
            raise LabelTableError(
                f"{source}: the table holds labels of {len(present)} levels "
                f"({', '.join(present)}); choose one with level=... (--level).")
        level = present[0]
    elif level not in sdl.LEVELS:
        raise did_you_mean("level", level, sdl.LEVELS)
    elif level not in present:
        raise LabelTableError(f"{source}: no labels at level {level!r}; the table has "
                              f"{', '.join(present) or 'none'}. Label at that level with "
                              f"'tap-bench label --level {level}' (or --level all).")
    rows = (labels["level"].astype(str) == level).to_numpy()
    return labels.loc[rows], level


def label_text(labels: pd.DataFrame, axes=None) -> pd.Series:
    """The label of each row on ``axes``: its sequences joined by ``" | "`` (``sdl`` for
    TAP's two axes); NA where an axis is empty (a track not labelled on that axis)."""
    axes = sdl.check_axes(axes)
    if axes == sdl.AXES and "sdl" in labels.columns:
        return labels["sdl"]
    missing = [a for a in axes if a not in labels.columns]
    if missing:
        raise LabelTableError(_missing_axes(missing))
    arrays = [pa.array(labels[a].astype("string"), type=pa.large_string()) for a in axes]
    joined = arrays[0] if len(arrays) == 1 else pc.binary_join_element_wise(
        *arrays, pa.scalar(sdl.SDL_SEPARATOR, pa.large_string()))
    return pd.Series(joined.to_pandas(), index=labels.index, dtype="string")


def _missing_axes(missing: list[str]) -> str:
    fix = (" Label with 'tap-bench label --interactions' (tap(..., interactions='auto'))."
           if "interaction" in missing else " Make the table with 'tap-bench label'.")
    return f"no {', '.join(map(repr, missing))} column for the axes asked for.{fix}"


def label_set(labels: pd.DataFrame | LabelSet, level: str | None = None, *, axes=None,
              source: str = "label table") -> LabelSet:
    """Encode one level of a label table (SPEC section 1) for search and comparison.

    Args:
        labels: a label table (or a :class:`LabelSet`, returned as it is when its level and
            axes fit).
        level: the SDL level; may be omitted when the table holds a single level.
        axes: the axes to compare (default TAP's lateral and longitudinal; ``interaction``
            needs a table labelled with interactions, whose rows without an interaction
            label are left out).
        source: a name for the table in error messages (its file path).

    Raises:
        LabelTableError: missing columns, empty labels, an ``sdl`` that is not
            ``lateral | longitudinal``, or a token outside the level's vocabulary; each names
            the row and the fix.
    """
    axes = sdl.check_axes(axes)
    if isinstance(labels, LabelSet):
        if level is not None and labels.level not in (None, level):
            raise LabelTableError(f"{source}: a LabelSet of level {labels.level!r} was given "
                                  f"where level {level!r} was asked for.")
        if labels.axes != axes:
            raise LabelTableError(f"{source}: a LabelSet of axes {labels.axes} was given "
                                  f"where axes {axes} were asked for.")
        return labels
    if not isinstance(labels, pd.DataFrame):
        raise TypeError(f"{source}: expected a pandas DataFrame, got {type(labels).__name__}")
    required = ("scenario_id", "track_id", *axes, *(("sdl",) if axes == sdl.AXES else ()))
    missing = [c for c in required if c not in labels.columns]
    if missing:
        extra = [a for a in missing if a == "interaction"]
        if extra:
            raise LabelTableError(f"{source}: {_missing_axes(extra)}")
        raise LabelTableError(
            f"{source}: missing column(s) {', '.join(map(repr, missing))}; a label table has "
            f"{', '.join(REQUIRED_LABEL_COLUMNS)} (and level, t_start, t_end): make it with "
            "'tap-bench label'.")
    table, level = _select_level(labels, level, source)
    # Keep the input's row numbers (before level selection) for error messages.
    input_rows = np.flatnonzero(labels["level"].astype(str).to_numpy() == level) \
        if "level" in labels.columns else np.arange(len(labels))
    if "interaction" in axes:  # tracks not labelled on that axis (not egos) are left out
        on_axis = table["interaction"].notna().to_numpy()
        if not on_axis.any():
            raise LabelTableError(f"{source}: no row carries an interaction label; label the "
                                  "table with --interactions (or --interactions all).")
        table, input_rows = table.loc[on_axis], input_rows[on_axis]
    if len(table) == 0:
        raise LabelTableError(f"{source}: the label table is empty.")
    table = table.reset_index(drop=True)

    for col in (*axes, *(("sdl",) if axes == sdl.AXES else ())):
        empty = table[col].isna().to_numpy()
        if empty.any():
            pos = int(np.flatnonzero(empty)[0])
            raise LabelTableError(f"{source}: column {col!r} is empty at row "
                                  f"{int(input_rows[pos])} ({_key(table, pos)}); every row needs "
                                  "a label.")
    text = label_text(table, axes).astype(str)
    code, uniques = pd.factorize(text, sort=False)
    uniques = np.asarray(uniques, dtype=object)
    n_u = len(uniques)
    counts = np.bincount(code, minlength=n_u).astype(np.int64)
    first_row = np.full(n_u, len(code), dtype=np.int64)
    np.minimum.at(first_row, code, np.arange(len(code), dtype=np.int64))

    if axes == sdl.AXES:  # sdl must be lateral | longitudinal on every row (one pass)
        def arrow(col: str) -> pa.Array:
            return pa.array(table[col].astype(str), type=pa.large_string())

        joined = pc.binary_join_element_wise(arrow("lateral"), arrow("longitudinal"),
                                             pa.scalar(sdl.SDL_SEPARATOR, pa.large_string()))
        bad = ~np.asarray(pc.equal(joined, arrow("sdl")), dtype=bool)
        if bad.any():
            pos = int(np.flatnonzero(bad)[0])
            raise LabelTableError(
                f"{source}: row {int(input_rows[pos])} ({_key(table, pos)}): sdl "
                f"{table['sdl'].iloc[pos]!r} is not lateral + {sdl.SDL_SEPARATOR!r} + "
                f"longitudinal ({table['lateral'].iloc[pos]!r}, "
                f"{table['longitudinal'].iloc[pos]!r}). Rebuild the table with "
                "'tap-bench label'.")

    k = len(axes)
    axis_index = np.empty((n_u, k), dtype=np.int64)
    n_tokens = np.empty((n_u, k), dtype=np.int64)
    indexes: list[dict[str, int]] = [{} for _ in axes]
    for u, label in enumerate(uniques):
        try:
            parts = parse_sdl(label, level=level, axes=axes)
        except LabelTableError as err:
            row = int(first_row[u])
            column = "sdl" if axes == sdl.AXES else "/".join(axes)
            raise LabelTableError(f"{source}: row {int(input_rows[row])} ({_key(table, row)}), "
                                  f"column {column!r}: {err}") from None
        for j, (tokens, axis) in enumerate(zip(parts, axes, strict=True)):
            axis_index[u, j] = indexes[j].setdefault(_encode(tokens, axis), len(indexes[j]))
            n_tokens[u, j] = len(tokens)
    return LabelSet(table=table, level=level, axes=axes, code=code.astype(np.int64),
                    labels=uniques, counts=counts, first_row=first_row,
                    axis_index=axis_index, axis_strings=tuple(list(ix) for ix in indexes),
                    n_tokens=n_tokens)


def _key(table: pd.DataFrame, pos: int) -> str:
    parts = [f"{c}={table[c].iloc[pos]!r}" for c in ("scenario_id", "track_id", "segment")
             if c in table.columns]
    return ", ".join(parts)


def levenshtein_matrix(labels: LabelSet, rows: np.ndarray | None = None,
                       workers: int = 1) -> np.ndarray:
    """Levenshtein distances between distinct labels (summed over the set's axes).

    Args:
        labels: an encoded label set.
        rows: (r,) indices of distinct labels to compute rows for (default: all u).
        workers: threads for rapidfuzz.

    Returns:
        (r, u) int32: distance from each label of ``rows`` to every distinct label.
    """
    rows = np.arange(labels.n_labels) if rows is None else np.asarray(rows, dtype=np.int64)
    out = np.zeros((len(rows), labels.n_labels), dtype=np.int32)
    for j, strings in enumerate(labels.axis_strings):
        of = labels.axis_index[:, j]
        # Only the distinct sequences of ``rows`` against every distinct sequence: the work
        # the answer needs, and never a full u-by-u matrix of a fine-grained level.
        mine, inverse = np.unique(of[rows], return_inverse=True)
        d = cdist([strings[i] for i in mine], strings, scorer=Levenshtein.distance,
                  dtype=np.int32, workers=workers)
        out += d[np.ix_(inverse.ravel(), of)]
    return out
