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
from rapidfuzz.distance import Levenshtein
from rapidfuzz.process import cdist

from tap_bench import sdl
from tap_bench.errors import LabelTableError
from tap_bench.labels import label_text, row_key, validate_labels
from tap_bench.sdl import parse_sdl

__all__ = [
    "METRICS",
    "LabelSet",
    "g_sdl",
    "label_set",
    "levenshtein_matrix",
    "sdl_levenshtein",
]

METRICS = ("exact", "levenshtein")
"""Label distances: ``exact`` is g_SDL (0 or 1), ``levenshtein`` the token edit distance."""

# One character per label of each axis in the encoded strings.
_CHAR = {axis: {tok: chr(0x41 + i) for i, tok in enumerate(sdl.tokens(axis))}
         for axis in sdl.LABEL_AXES}


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
    table, level, input_rows = validate_labels(labels, level, source=source, axes=axes)
    text = label_text(table, axes).astype(str)
    code, uniques = pd.factorize(text, sort=False)
    uniques = np.asarray(uniques, dtype=object)
    n_u = len(uniques)
    counts = np.bincount(code, minlength=n_u).astype(np.int64)
    first_row = np.full(n_u, len(code), dtype=np.int64)
    np.minimum.at(first_row, code, np.arange(len(code), dtype=np.int64))

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
            raise LabelTableError(f"{source}: row {int(input_rows[row])} "
                                  f"({row_key(table, row)}), column {column!r}: {err}") from None
        for j, (tokens, axis) in enumerate(zip(parts, axes, strict=True)):
            axis_index[u, j] = indexes[j].setdefault(_encode(tokens, axis), len(indexes[j]))
            n_tokens[u, j] = len(tokens)
    return LabelSet(table=table, level=level, axes=axes, code=code.astype(np.int64),
                    labels=uniques, counts=counts, first_row=first_row,
                    axis_index=axis_index, axis_strings=tuple(list(ix) for ix in indexes),
                    n_tokens=n_tokens)


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
