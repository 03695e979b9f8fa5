"""Progress bars of the command line: shown only on a terminal unless asked.

``--progress`` shows the bar whatever stderr is; ``--no-progress`` never shows it; without
either, the bar is shown only when stderr is a terminal, so pipes and log files get none.
"""

from __future__ import annotations

import argparse

__all__ = ["add_progress_arguments", "progress_choice"]


def add_progress_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--progress`` / ``--no-progress`` (mutually exclusive) to ``parser``."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--progress", dest="progress", action="store_true", default=None,
                       help="show a progress bar even when stderr is not a terminal")
    group.add_argument("--no-progress", dest="progress", action="store_false",
                       help="no progress bar (default: one only on a terminal)")


def progress_choice(args: argparse.Namespace) -> bool | None:
    """True (``--progress``), False (``--no-progress``) or None (only on a terminal)."""
    return getattr(args, "progress", None)
