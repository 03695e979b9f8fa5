"""The ``tap-bench`` command line.

Each sub-command lives in its own module of this package, which defines
``add_parser(subparsers)``; the parser it adds sets ``func`` (taking the parsed arguments and
returning an exit code). Add a module to ``COMMANDS`` to register it.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys
import threading
from collections.abc import Sequence

from tap_bench.errors import TapBenchError

COMMANDS = (
    "tap_bench.cli.sample",
    "tap_bench.cli.label",
    "tap_bench.cli.fit",
    "tap_bench.cli.ingest",
    "tap_bench.cli.validate",
    # simulation: highway-env scenarios, policies, rollouts, training
    "tap_bench.cli.envs",
    "tap_bench.cli.policies",
    "tap_bench.cli.rollout",
    "tap_bench.cli.train",
    # the benchmark: matched comparison, coverage, suite runs and the regression gate
    "tap_bench.cli.compare",
    "tap_bench.cli.contexts",
    "tap_bench.cli.coverage",
    "tap_bench.cli.gap",
    "tap_bench.cli.bench",
    "tap_bench.cli.demo",
    "tap_bench.cli.view",
    # similarity: SDL search, unique behaviours, the paper's ADE / DTW experiments
    "tap_bench.cli.search",
    "tap_bench.cli.unique",
    "tap_bench.cli.export",
    "tap_bench.cli.evaluate",
)


def build_parser() -> argparse.ArgumentParser:
    from tap_bench import __version__

    parser = argparse.ArgumentParser(
        prog="tap-bench",
        description="Scenario benchmark toolkit: TAP (Trajectory-to-Action Pipeline) labels "
        "driving behaviour as Scenario Description Language (SDL) labels.",
    )
    parser.add_argument("--version", action="version", version=f"tap-bench {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(name).add_parser(sub)
    return parser


def _terminate(signum: int, frame: object) -> None:
    """SIGTERM ends a command as Ctrl-C does: cleanup runs, workers stop, nothing partial
    is left (outputs are written atomically)."""
    raise KeyboardInterrupt


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``tap-bench``; returns the process exit code.

    Exit codes: 0 success, 1 the command ran but its check failed (a regression, every
    episode failed), 2 a usage or input error (every :class:`TapBenchError`, printed as one
    message), 130 interrupted (Ctrl-C or SIGTERM).
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        return int(args.func(args) or 0)
    except TapBenchError as err:
        print(f"tap-bench {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"tap-bench {args.command}: interrupted; no partial output was written.",
              file=sys.stderr)
        return 130
    except BrokenPipeError:
        # the reader of our output went away (tap-bench policies | head): not an error
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
