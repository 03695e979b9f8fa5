"""Distances between SDL labels: exact (g_SDL) and Levenshtein over label tokens.

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
from tap_bench.labels import row_key, validate_labels
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
         for axis in sdl.AXES}


def g_sdl(a: str, b: str) -> int:
    """The paper's g_SDL: 0 when the two SDL labels are equal, 1 otherwise."""
    return int(a != b)


def sdl_levenshtein(a: str, b: str) -> int:
    """Levenshtein distance between two SDL labels over whole label tokens.

    The lateral edit distance plus the longitudinal edit distance; each insertion, deletion
    or substitution of one label costs 1. ``"Straight | Maintain Medium Speed"`` against
    ``"Straight > Gradual Left Turn > Straight | Maintain Medium Speed"`` is 2.
    """
    (lat_a, lon_a), (lat_b, lon_b) = parse_sdl(a), parse_sdl(b)
    return int(Levenshtein.distance(lat_a, lat_b) + Levenshtein.distance(lon_a, lon_b))


def _encode(tokens: tuple[str, ...] | list[str], axis: str) -> str:
    return "".join(_CHAR[axis][tok] for tok in tokens)


@dataclass(frozen=True)
class LabelSet:
    """One level of a label table, encoded for fast comparison.

    Rows are the label table's rows at that level, in their input order; a row is one
    trajectory (one valid segment of a track).

    Attributes:
        table: (n rows) the label rows at ``level``, index reset.
        level: the SDL level (``trace`` ... ``action``), or None when the table has no
            ``level`` column.
        code: (n,) int64, index of each row's SDL label in ``labels``.
        labels: (u,) the distinct SDL labels (object array of str), in order of first use.
        counts: (u,) int64, rows holding each distinct label.
        first_row: (u,) int64, the first row holding each label.
        lateral: (u,) int64, index of each label's lateral sequence in ``lateral_strings``.
        longitudinal: (u,) int64, likewise in ``longitudinal_strings``.
        lateral_strings: distinct lateral sequences, one character per token.
        longitudinal_strings: distinct longitudinal sequences, one character per token.
        n_lateral: (u,) int64 tokens in each label's lateral sequence.
        n_longitudinal: (u,) int64 tokens in each label's longitudinal sequence.
    """

    table: pd.DataFrame
    level: str | None
    code: np.ndarray
    labels: np.ndarray
    counts: np.ndarray
    first_row: np.ndarray
    lateral: np.ndarray
    longitudinal: np.ndarray
    lateral_strings: list[str]
    longitudinal_strings: list[str]
    n_lateral: np.ndarray
    n_longitudinal: np.ndarray

    def __len__(self) -> int:
        return len(self.code)

    @property
    def n_labels(self) -> int:
        return len(self.labels)

    def encode(self, text: str) -> tuple[str, str]:
        """An SDL label as (lateral, longitudinal) encoded strings, checked at this level."""
        lat, lon = parse_sdl(text, level=self.level)
        return _encode(lat, "lateral"), _encode(lon, "longitudinal")

    def levenshtein_to(self, text: str) -> np.ndarray:
        """(u,) int32 Levenshtein distance from ``text`` to each distinct label."""
        lat, lon = self.encode(text)
        d_lat = cdist([lat], self.lateral_strings, scorer=Levenshtein.distance, dtype=np.int32)[0]
        d_lon = cdist([lon], self.longitudinal_strings, scorer=Levenshtein.distance,
                      dtype=np.int32)[0]
        return d_lat[self.lateral] + d_lon[self.longitudinal]


def label_set(labels: pd.DataFrame | LabelSet, level: str | None = None, *,
              source: str = "label table") -> LabelSet:
    """Encode one level of a label table (SPEC section 1) for search and comparison.

    Args:
        labels: a label table (or a :class:`LabelSet`, returned as it is when its level fits).
        level: the SDL level; may be omitted when the table holds a single level.
        source: a name for the table in error messages (its file path).

    Raises:
        LabelTableError: missing columns, empty labels, an ``sdl`` that is not
            ``lateral | longitudinal``, or a token outside the level's vocabulary; each names
            the row and the fix.
    """
    if isinstance(labels, LabelSet):
        if level is not None and labels.level not in (None, level):
            raise LabelTableError(f"{source}: a LabelSet of level {labels.level!r} was given "
                                  f"where level {level!r} was asked for.")
        return labels
    table, level, input_rows = validate_labels(labels, level, source=source)
    code, uniques = pd.factorize(table["sdl"].astype(str), sort=False)
    uniques = np.asarray(uniques, dtype=object)
    n_u = len(uniques)
    counts = np.bincount(code, minlength=n_u).astype(np.int64)
    first_row = np.full(n_u, len(code), dtype=np.int64)
    np.minimum.at(first_row, code, np.arange(len(code), dtype=np.int64))

    lat_of = np.empty(n_u, dtype=np.int64)
    lon_of = np.empty(n_u, dtype=np.int64)
    lat_index: dict[str, int] = {}
    lon_index: dict[str, int] = {}
    n_lat = np.empty(n_u, dtype=np.int64)
    n_lon = np.empty(n_u, dtype=np.int64)
    for u, text in enumerate(uniques):
        try:
            lat, lon = parse_sdl(text, level=level)
        except LabelTableError as err:
            row = int(first_row[u])
            raise LabelTableError(f"{source}: row {int(input_rows[row])} ({row_key(table, row)}), "
                                  f"column 'sdl': {err}") from None
        lat_of[u] = lat_index.setdefault(_encode(lat, "lateral"), len(lat_index))
        lon_of[u] = lon_index.setdefault(_encode(lon, "longitudinal"), len(lon_index))
        n_lat[u], n_lon[u] = len(lat), len(lon)
    return LabelSet(table=table, level=level, code=code.astype(np.int64), labels=uniques,
                    counts=counts, first_row=first_row, lateral=lat_of, longitudinal=lon_of,
                    lateral_strings=list(lat_index), longitudinal_strings=list(lon_index),
                    n_lateral=n_lat, n_longitudinal=n_lon)


def levenshtein_matrix(labels: LabelSet, rows: np.ndarray | None = None,
                       workers: int = 1) -> np.ndarray:
    """Levenshtein distances between distinct labels.

    Args:
        labels: an encoded label set.
        rows: (r,) indices of distinct labels to compute rows for (default: all u).
        workers: threads for rapidfuzz.

    Returns:
        (r, u) int32: distance from each label of ``rows`` to every distinct label.
    """
    rows = np.arange(labels.n_labels) if rows is None else np.asarray(rows, dtype=np.int64)
    out = np.zeros((len(rows), labels.n_labels), dtype=np.int32)
    for axis, strings in (("lateral", labels.lateral_strings),
                          ("longitudinal", labels.longitudinal_strings)):
        of = getattr(labels, axis)
        # Only the distinct sequences of ``rows`` against every distinct sequence: the work
        # the answer needs, and never a full u-by-u matrix of a fine-grained level.
        mine, inverse = np.unique(of[rows], return_inverse=True)
        d = cdist([strings[i] for i in mine], strings, scorer=Levenshtein.distance,
                  dtype=np.int32, workers=workers)
        out += d[np.ix_(inverse.ravel(), of)]
    return out
