"""Progress output of long runs: a bar on a terminal, plain lines in a log.

``--progress`` shows the bar whatever stderr is; ``--no-progress`` shows nothing; without
either, a terminal gets the bar and anything else (a log file, a pipe, CI) a plain line on
stderr every :data:`LINE_EVERY` seconds while the work runs (none for work done sooner),
so a run whose output goes to a file is never silent for minutes.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from typing import Any, TextIO

__all__ = ["LINE_EVERY", "ProgressLines", "SceneProgress", "SilentProgress",
           "add_progress_arguments", "progress_bar", "progress_choice"]

LINE_EVERY = 5.0
"""Seconds between two progress lines where stderr is not a terminal [s]."""


def add_progress_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--progress`` / ``--no-progress`` (mutually exclusive) to ``parser``."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--progress", dest="progress", action="store_true", default=None,
                       help="show a progress bar even when stderr is not a terminal")
    group.add_argument("--no-progress", dest="progress", action="store_false",
                       help="no progress output (default: a bar on a terminal, else a line "
                       f"on stderr every {LINE_EVERY:g} s)")


def progress_choice(args: argparse.Namespace) -> bool | None:
    """True (``--progress``), False (``--no-progress``) or None (a bar on a terminal, else
    lines)."""
    return getattr(args, "progress", None)


class ProgressLines:
    """A progress display for logs, with the part of tqdm's interface the runs use
    (``update``, ``close``, a context manager): from a background thread, one line
    ``"<desc>: <done>/<total> <unit>s, <elapsed> s[, about <left> s left]"`` on ``stream``
    every ``every`` seconds until closed, and a last line on closing if it wrote any.

    Args:
        total: items to do (None: unknown, no estimate of the time left).
        desc: what runs (the bar's title).
        unit: what an item is (``"episode"``, ``"task"``).
        every: seconds between lines [s] (default: :data:`LINE_EVERY`).
        stream: where the lines go (default: ``sys.stderr`` when each line is written).
    """

    def __init__(self, total: int | None = None, desc: str = "", unit: str = "item", *,
                 every: float | None = None, stream: TextIO | None = None):
        self.total, self.desc, self.unit = total, desc, unit
        self.every = LINE_EVERY if every is None else every
        self.stream = stream
        self.n = 0
        self.lines = 0
        self._start = time.monotonic()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="tap-bench progress",
                                        daemon=True)
        self._thread.start()

    def update(self, n: int = 1) -> None:
        self.n += n

    def line(self) -> str:
        """The progress line as it stands."""
        elapsed = time.monotonic() - self._start
        done = f"{self.n}/{self.total}" if self.total is not None else f"{self.n}"
        text = f"{self.desc or 'progress'}: {done} {self.unit}s, {elapsed:.0f} s"
        if self.total and 0 < self.n < self.total:
            text += f", about {elapsed * (self.total - self.n) / self.n:.0f} s left"
        return text

    def _write(self, text: str) -> None:
        stream = self.stream if self.stream is not None else sys.stderr
        try:
            print(text, file=stream, flush=True)
        except (OSError, ValueError):  # a closed stream: progress is not worth an error
            self._stop.set()
        self.lines += 1

    def _run(self) -> None:
        while not self._stop.wait(self.every):
            self._write(self.line())

    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join()
        if self.lines:
            self._write(self.line())

    def __enter__(self) -> ProgressLines:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class SilentProgress:
    """A progress display that shows nothing, with the part of tqdm's interface the runs
    use (``update``, ``close``, ``n``, a context manager)."""

    def __init__(self, total: int | None = None) -> None:
        self.total, self.n = total, 0

    def update(self, n: int = 1) -> None:
        self.n += n

    def close(self) -> None:
        """Nothing to close."""

    def __enter__(self) -> SilentProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _stderr_is_terminal() -> bool:
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):
        return False


def progress_bar(total: int | None, desc: str = "", unit: str = "item",
                 progress: bool | None = None) -> Any:
    """What shows a run's progress: a tqdm bar (``progress`` True, or None on a terminal),
    :class:`ProgressLines` (None anywhere else) or a disabled bar (False)."""
    if progress is False:  # nothing shown: no tqdm to import
        return SilentProgress(total)
    if progress is None and not _stderr_is_terminal():
        return ProgressLines(total, desc, unit)
    from tqdm.auto import tqdm  # a progress bar only where one is drawn

    return tqdm(total=total, desc=desc or None, unit=unit, disable=not progress
                if progress is not None else None)


class SceneProgress:
    """Progress of a run over many scenes, as one line on stderr (terminal or not) and in a
    log file alike, at most every ``every`` seconds, and a last line when closed::

        idm: 120/245 scenes (20 before), 2 failed, 1 skipped, 0.61 scenes/s, about 205 s left

    The rate counts this run's scenes only (those done before a resume took no time here);
    the time left is the scenes left at that rate.

    Args:
        total: scenes of the run.
        desc: what runs.
        before: scenes done by an earlier, interrupted run (counted as done).
        show: write to stderr (the log file is written whatever ``show`` is).
        unit: what an item is (``"scene"``; ``"episode"`` for generated scenarios).
        log: a file the lines are appended to (None: none).
        every: seconds between two lines [s] (default :data:`LINE_EVERY`).
    """

    def __init__(self, total: int, desc: str = "", *, before: int = 0, show: bool = True,
                 log: str | None = None, every: float | None = None, unit: str = "scene"):
        self.total, self.desc, self.before, self.show = total, desc, before, show
        self.unit = unit
        self.done = self.failed = self.skipped = 0
        self.every = LINE_EVERY if every is None else every
        self.log = open(log, "a", encoding="utf-8") if log else None
        self._start = time.monotonic()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="tap-bench scenes",
                                        daemon=True)
        self._thread.start()

    def update(self, status: str) -> None:
        """One scene finished with ``status`` (``"ok"``, ``"skipped"`` or a failure)."""
        with self._lock:
            self.done += 1
            if status == "skipped":
                self.skipped += 1
            elif status != "ok":
                self.failed += 1

    def line(self) -> str:
        """The progress line as it stands."""
        with self._lock:
            done, failed, skipped = self.done, self.failed, self.skipped
        elapsed = max(time.monotonic() - self._start, 1e-9)
        text = f"{self.desc or 'run'}: {self.before + done}/{self.total} {self.unit}s"
        if self.before:
            text += f" ({self.before} before)"
        text += f", {failed} failed, {skipped} skipped"
        rate = done / elapsed
        text += f", {rate:.2f} {self.unit}s/s" if done else ", starting"
        left = self.total - self.before - done
        if done and left > 0:
            text += f", about {left / rate:.0f} s left"
        elif left <= 0:
            text += f", {elapsed:.0f} s"
        return text

    def note(self, text: str) -> None:
        """Write one line (to stderr when shown, and to the log file)."""
        stamp = time.strftime("%Y-%m-%d %H:%M:%S")
        for stream, prefix in ((sys.stderr if self.show else None, ""),
                               (self.log, f"{stamp} ")):
            if stream is None:
                continue
            try:
                print(prefix + text, file=stream, flush=True)
            except (OSError, ValueError):  # a closed stream: progress is not worth an error
                pass

    def _run(self) -> None:
        while not self._stop.wait(self.every):
            self.note(self.line())

    def close(self) -> None:
        if self._stop.is_set():
            return
        self._stop.set()
        self._thread.join()
        self.note(self.line())
        if self.log is not None:
            self.log.close()

    def __enter__(self) -> SceneProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
