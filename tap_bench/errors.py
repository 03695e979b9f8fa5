"""The tap-bench error hierarchy.

Every error a user can cause names where the problem is (file, row, column or field), what
was wrong and how to fix it. Catch :class:`TapBenchError` to catch them all; each concrete
error is also a :class:`ValueError` (or :class:`KeyError`) so generic handlers keep working.
"""

from __future__ import annotations

import difflib
import os
import sys
import warnings
from collections.abc import Iterable

__all__ = [
    # errors
    "TapBenchError",
    "ParameterError",
    "TrajectoryTableError",
    "LabelTableError",
    "ThresholdsError",
    "FileFormatError",
    "WomdRecordError",
    "StateDecodeError",
    "UnknownNameError",
    "SuiteError",
    "CatalogueError",
    "RunExistsError",
    "OutputPathError",
    "BaselineError",
    "BaselineMismatchError",
    "EpisodesFailedError",
    "RegistrationError",
    # warnings
    "ShortSegmentWarning",
    "FewClustersWarning",
    "ResampledWarning",
    "FitWarning",
    "EpisodeFailedWarning",
    "UntrustedModelWarning",
    "CacheEntryWarning",
    "did_you_mean",
    "warn_caller",
]


class TapBenchError(Exception):
    """Base class of every error raised on purpose by tap-bench."""


class ParameterError(TapBenchError, ValueError):
    """A parameter (of a function or a command line option) has a value it cannot take.

    The message names the parameter, the value received and what is allowed (the
    scikit-learn convention).

    Attributes:
        parameter: the parameter's name (``workers``, ``--seeds``).
        value: the value received.
        allowed: what is allowed, in words.
    """

    def __init__(self, parameter: str, value: object, allowed: str, *, hint: str = "",
                 message: str | None = None):
        self.parameter = parameter
        self.value = value
        self.allowed = allowed
        self.hint = hint
        if message is None:
            message = f"{parameter} must be {allowed}, got {value!r}." + (
                f" {hint}" if hint else "")
        super().__init__(message)

    def __reduce__(self):  # keeps the attributes across worker processes
        return (_rebuild_parameter_error, (self.parameter, self.value, self.allowed,
                                           self.hint, str(self)))


def _rebuild_parameter_error(parameter: str, value: object, allowed: str, hint: str,
                             message: str) -> ParameterError:
    return ParameterError(parameter, value, allowed, hint=hint, message=message)


class TrajectoryTableError(TapBenchError, ValueError):
    """A trajectory table breaks the contract of SPEC section 1.

    Attributes:
        column: the offending column, when one is to blame.
        row: the 0-based position of the first offending row in the input, when known.
        rate_hz: the table's sampling rate [Hz] when the error is that it is not 10 Hz
            (:func:`tap_bench.tap` resamples faster input on entry).
    """

    def __init__(self, message: str, *, column: str | None = None, row: int | None = None,
                 rate_hz: float | None = None):
        super().__init__(message)
        self.column = column
        self.row = row
        self.rate_hz = rate_hz


class LabelTableError(TapBenchError, ValueError):
    """A label or segment table breaks its contract."""


class ThresholdsError(TapBenchError, ValueError):
    """Thresholds that are out of order, malformed, or a thresholds file that cannot be read."""


class FileFormatError(TapBenchError, ValueError):
    """A file that tap-bench cannot read or write (unknown suffix, unreadable content)."""


class WomdRecordError(FileFormatError):
    """A record of a WOMD (or other driving-data) file is damaged or is not what the reader
    expects.

    The message names the file, the record (0-based) and its byte offset, what was wrong and
    the fix.

    Attributes:
        path: the file.
        record: 0-based index of the record in the file.
        offset: byte offset of the record's start (in the decompressed stream of a GZIP file).
        problem: what was wrong, without the location.
        resumable: whether the records after this one can still be read (false when the
            framing itself is broken: the next record's start is unknown).
    """

    def __init__(self, path: str, record: int, offset: int, problem: str, fix: str,
                 resumable: bool = True):
        self.path = str(path)
        self.record = record
        self.offset = offset
        self.problem = problem
        self.fix = fix
        self.resumable = resumable
        super().__init__(f"{path}: record {record} at byte {offset}: {problem}. {fix}")

    def __reduce__(self):  # keeps the attributes across worker processes
        return (type(self), (self.path, self.record, self.offset, self.problem, self.fix,
                             self.resumable))

    def as_dict(self) -> dict:
        """The location and the problem, for a report."""
        return {"path": self.path, "record": self.record, "offset": self.offset,
                "problem": self.problem}


class StateDecodeError(TapBenchError, ValueError):
    """Bytes that are not WOMD ObjectState messages (raised by the vectorised decoder).

    Attributes:
        state: index of the first malformed state in the input order.
    """

    def __init__(self, message: str, state: int):
        super().__init__(message)
        self.state = state

    def __reduce__(self):
        return (type(self), (str(self), self.state))


class CatalogueError(TapBenchError, FileNotFoundError):
    """The built-in scenarios and policies (or a catalogue folder) cannot be found."""


class SuiteError(TapBenchError, ValueError):
    """A scenario, policy or suite file (or definition) that breaks its format."""


class RunExistsError(TapBenchError, FileExistsError):
    """The results folder exists and replacing it was not asked for."""


class OutputPathError(TapBenchError, ValueError):
    """An output that must not or cannot be written: it is one of the inputs, it would
    replace something tap-bench did not write (a file, a link, a folder without tap-bench's
    marker), or its place is not writable."""


class BaselineError(TapBenchError, ValueError):
    """A baseline file that cannot be used (malformed, or a run that cannot become one)."""


class BaselineMismatchError(BaselineError):
    """The run and the baseline were not made with the same suite, level or thresholds."""


class EpisodesFailedError(TapBenchError, RuntimeError):
    """Every episode of a rollout or a suite run failed: there is no result to return.

    Attributes:
        what: what was run ("4 episodes of idm on highway").
        errors: the first errors, one line each (``"seed 0: RuntimeError: ..."``).
    """

    def __init__(self, what: str, errors: list[str]):
        self.what = what
        self.errors = list(errors)
        listed = "; ".join(self.errors[:3])
        more = f" (and {len(self.errors) - 3} more)" if len(self.errors) > 3 else ""
        super().__init__(f"every one of {what} failed, so there is no result. The first "
                         f"errors: {listed}{more}. Fix the first error (run one seed with "
                         "workers=1 to see its traceback) and run again.")

    def __reduce__(self):
        return (type(self), (self.what, self.errors))


class UnknownNameError(TapBenchError, KeyError):
    """A name (preset, level, policy, env ...) that is not registered."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])


class FitWarning(UserWarning):
    """A threshold fit to look at: its J far above the grid optimum, or a degenerate band
    (SPEC section 3)."""


class ResampledWarning(UserWarning):
    """A table sampled faster than 10 Hz was resampled to 10 Hz on entry (SPEC 4.7)."""


class FewClustersWarning(UserWarning):
    """A bootstrap interval rests on fewer than ten independent units (scenes, episodes)
    on a side: it covers less than its level (:mod:`tap_bench.stats.bootstrap`)."""


class ShortSegmentWarning(UserWarning):
    """Valid segments shorter than 1 s were found: they cannot carry a label (SPEC section 2)."""


class EpisodeFailedWarning(UserWarning):
    """Some episodes of a rollout raised; they are listed in the episode table."""


class UntrustedModelWarning(UserWarning):
    """A Stable-Baselines3 model file (pickles) is being loaded: it can run code."""


class CacheEntryWarning(UserWarning):
    """An episode cache entry failed its checks: it was deleted and its episode simulated
    again (:mod:`tap_bench.bench.cache`)."""


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


class RegistrationError(TapBenchError, ValueError):
    """A registry entry that is refused: a name registered twice, or an entry that lacks a
    required field (a measure without a gate margin)."""


_PACKAGE = os.path.dirname(os.path.abspath(__file__)) + os.sep


def warn_caller(message: str, category: type[Warning] = UserWarning) -> None:
    """Warn ``message``, attributed to the first caller outside tap-bench (the user's line
    that called into it, however deep the call that warns): ``skip_file_prefixes`` of
    :func:`warnings.warn` (Python 3.12+), the frames counted on older versions."""
    if sys.version_info >= (3, 12):
        warnings.warn(message, category, skip_file_prefixes=(_PACKAGE,))
        return
    level, frame = 2, sys._getframe(1)  # 2: this function's caller
    while frame is not None and frame.f_code.co_filename.startswith(_PACKAGE):
        level, frame = level + 1, frame.f_back
    warnings.warn(message, category, stacklevel=level)
