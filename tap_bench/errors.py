"""The tap-bench error hierarchy.

Every error a user can cause names where the problem is (file, row, column or field), what
was wrong and how to fix it. Catch :class:`TapBenchError` to catch them all; each concrete
error is also a :class:`ValueError` (or :class:`KeyError`) so generic handlers keep working.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable

__all__ = [
    "FileFormatError",
    "LabelTableError",
    "OutputExistsError",
    "OutputPathError",
    "ShortSegmentWarning",
    "TapBenchError",
    "ThresholdsError",
    "TrajectoryTableError",
    "UnknownNameError",
    "did_you_mean",
]


class TapBenchError(Exception):
    """Base class of every error raised on purpose by tap-bench."""


class TrajectoryTableError(TapBenchError, ValueError):
    """A trajectory table breaks the contract of SPEC section 1.

    Attributes:
        column: the offending column, when one is to blame.
        row: the 0-based position of the first offending row in the input, when known.
    """

    def __init__(self, message: str, *, column: str | None = None, row: int | None = None):
        super().__init__(message)
        self.column = column
        self.row = row


class LabelTableError(TapBenchError, ValueError):
    """A label or segment table breaks its contract."""


class ThresholdsError(TapBenchError, ValueError):
    """Thresholds that are out of order, malformed, or a thresholds file that cannot be read."""


class FileFormatError(TapBenchError, ValueError):
    """A file that tap-bench cannot read or write (unknown suffix, unreadable content)."""


class OutputPathError(TapBenchError, ValueError):
    """An output that must not or cannot be written: it is one of the inputs, it would
    replace something tap-bench did not write, or its place is not writable."""


class OutputExistsError(OutputPathError, FileExistsError):
    """A results folder exists and replacing it (``--overwrite``) was not asked for."""


class UnknownNameError(TapBenchError, KeyError):
    """A name (preset, level, policy, env ...) that is not registered."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])


class ShortSegmentWarning(UserWarning):
    """Valid segments shorter than 1 s were found: they cannot carry a label (SPEC section 2)."""


def did_you_mean(kind: str, name: str, known: Iterable[str]) -> UnknownNameError:
    """Build an :class:`UnknownNameError` for ``name`` with the closest known names.

    Args:
        kind: what ``name`` is, for the message ("level", "thresholds preset" ...).
        name: the name that was asked for.
        known: the names that exist.
    """
    known = sorted(known)
    # compared without case, so that 'HIGHWAY' finds 'highway' and 'IDM' finds 'idm'
    folded: dict[str, str] = {}
    for k in known:
        folded.setdefault(str(k).casefold(), k)
    close = [folded[c] for c in difflib.get_close_matches(
        str(name).casefold(), list(folded), n=3, cutoff=0.5)]
    hint = f" Did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
    return UnknownNameError(
        f"unknown {kind} {name!r}.{hint} Known: {', '.join(repr(k) for k in known)}."
    )
