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
    for axis in sdl.AXES
}
_CHAR = {axis: {tok: chr(0x41 + i) for i, tok in enumerate(toks)} for axis, toks in _TOKENS.items()}


def parse_sdl(text: str, *, level: str | None = None) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Split an SDL label into its lateral and longitudinal token sequences.

    Args:
        text: ``"<lateral> > <lateral> ... | <longitudinal> > ..."``.
        level: when given, every token must belong to that level's vocabulary.

    Returns:
        (lateral tokens, longitudinal tokens), each in chronological order.

    Raises:
        LabelTableError: no ``" | "`` separator, an empty side, or an unknown token (with the
            closest known tokens).
    """
    bar = sdl.SDL_SEPARATOR.strip()
    if not isinstance(text, str) or text.count(bar) != 1:
        raise LabelTableError(
            f"SDL label {text!r} must hold exactly one {sdl.SDL_SEPARATOR!r} between the lateral "
            f"and the longitudinal labels, e.g. 'Straight > Gradual Left Turn{sdl.SDL_SEPARATOR}"
            "Maintain Medium Speed'.")
    lat_text, lon_text = text.split(bar)
    return (_tokens(lat_text, "lateral", level, text), _tokens(lon_text, "longitudinal", level,
                                                                text))


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
    if not isinstance(labels, pd.DataFrame):
        raise TypeError(f"{source}: expected a pandas DataFrame, got {type(labels).__name__}")
    missing = [c for c in REQUIRED_LABEL_COLUMNS if c not in labels.columns]
    if missing:
        raise LabelTableError(
            f"{source}: missing column(s) {', '.join(map(repr, missing))}; a label table has "
            f"{', '.join(REQUIRED_LABEL_COLUMNS)} (and level, t_start, t_end): make it with "
            "'tap-bench label'.")
    table, level = _select_level(labels, level, source)
    if len(table) == 0:
        raise LabelTableError(f"{source}: the label table is empty.")
    table = table.reset_index(drop=True)
    # Keep the input's row numbers (before level selection) for error messages.
    input_rows = np.flatnonzero(labels["level"].astype(str).to_numpy() == level) \
        if "level" in labels.columns else np.arange(len(labels))

    for col in ("lateral", "longitudinal", "sdl"):
        empty = table[col].isna().to_numpy()
        if empty.any():
            pos = int(np.flatnonzero(empty)[0])
            raise LabelTableError(f"{source}: column {col!r} is empty at row "
                                  f"{int(input_rows[pos])} ({_key(table, pos)}); every row needs "
                                  "a label.")
    code, uniques = pd.factorize(table["sdl"].astype(str), sort=False)
    uniques = np.asarray(uniques, dtype=object)
    n_u = len(uniques)
    counts = np.bincount(code, minlength=n_u).astype(np.int64)
    first_row = np.full(n_u, len(code), dtype=np.int64)
    np.minimum.at(first_row, code, np.arange(len(code), dtype=np.int64))

    # sdl must be lateral | longitudinal on every row (checked in one vectorised pass).
    def arrow(col: str) -> pa.Array:
        return pa.array(table[col].astype(str), type=pa.large_string())

    joined = pc.binary_join_element_wise(arrow("lateral"), arrow("longitudinal"),
                                         pa.scalar(sdl.SDL_SEPARATOR, pa.large_string()))
    bad = ~np.asarray(pc.equal(joined, arrow("sdl")), dtype=bool)
    if bad.any():
        pos = int(np.flatnonzero(bad)[0])
        raise LabelTableError(
            f"{source}: row {int(input_rows[pos])} ({_key(table, pos)}): sdl "
            f"{table['sdl'].iloc[pos]!r} is not lateral + {sdl.SDL_SEPARATOR!r} + longitudinal "
            f"({table['lateral'].iloc[pos]!r}, {table['longitudinal'].iloc[pos]!r}). Rebuild "
            "the table with 'tap-bench label'.")

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
            raise LabelTableError(f"{source}: row {int(input_rows[row])} ({_key(table, row)}), "
                                  f"column 'sdl': {err}") from None
        lat_of[u] = lat_index.setdefault(_encode(lat, "lateral"), len(lat_index))
        lon_of[u] = lon_index.setdefault(_encode(lon, "longitudinal"), len(lon_index))
        n_lat[u], n_lon[u] = len(lat), len(lon)
    return LabelSet(table=table, level=level, code=code.astype(np.int64), labels=uniques,
                    counts=counts, first_row=first_row, lateral=lat_of, longitudinal=lon_of,
                    lateral_strings=list(lat_index), longitudinal_strings=list(lon_index),
                    n_lateral=n_lat, n_longitudinal=n_lon)


def _key(table: pd.DataFrame, pos: int) -> str:
    parts = [f"{c}={table[c].iloc[pos]!r}" for c in ("scenario_id", "track_id", "segment")
             if c in table.columns]
    return ", ".join(parts)


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
