"""The ``tap-bench`` command line.

Each sub-command lives in its own module of this package, which defines
``add_parser(subparsers)``; the parser it adds sets ``func`` (taking the parsed arguments and
returning an exit code). Add a module and its one-line help to ``COMMANDS`` to register it.

Only the module of the command being run is imported: ``tap-bench --help`` lists the
commands from ``COMMANDS`` alone, and ``tap-bench envs`` never imports the modules (and
their pandas, highway-env or numba) that ``tap-bench search`` needs.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import os
import signal
import sys
import threading
import warnings
from collections.abc import Sequence

from tap_bench.errors import TapBenchError

COMMANDS: dict[str, tuple[str, str]] = {
    # name: (module, the help line of 'tap-bench --help'; the module's add_parser says the same)
    "sample": ("tap_bench.cli.sample",
               "write a built-in synthetic trajectory table (no data needed)"),
    "label": ("tap_bench.cli.label", "label trajectories with SDL labels (TAP)"),
    "fit": ("tap_bench.cli.fit", "learn TAP thresholds from trajectories"),
    "ingest": ("tap_bench.cli.ingest", "convert a data set to a trajectory table"),
    "validate": ("tap_bench.cli.validate",
                 "compare TAP labels of WOMD tracks with Waymo's trajectory types"),
    # simulation: highway-env scenarios, policies, rollouts, training
    "envs": ("tap_bench.cli.envs", "list the scenario envs of the suite with their settings"),
    "policies": ("tap_bench.cli.policies", "list the available driving policies"),
    "rollout": ("tap_bench.cli.rollout", "run a policy on a scenario for a set of seeds"),
    "train": ("tap_bench.cli.train",
              "train a Stable-Baselines3 agent (DQN, PPO, A2C) on a scenario"),
    "agents": ("tap_bench.cli.agents",
               "judge agents on real scenes over training seeds, against the human"),
    # the benchmark: matched comparison, coverage, suite runs and the regression gate
    "compare": ("tap_bench.cli.compare",
                "compare two policies: paired by seed and matched by SDL label"),
    "contexts": ("tap_bench.cli.contexts",
                 "compare two policies inside interaction contexts (cut-in, ...)"),
    "coverage": ("tap_bench.cli.coverage",
                 "how much of a reference's behaviour an agent shows, and what is new"),
    "gap": ("tap_bench.cli.gap",
            "how far policies drive from real driving (per label and one number)"),
    "bench": ("tap_bench.cli.bench", "run a benchmark suite; check a run against a baseline"),
    "demo": ("tap_bench.cli.demo",
             "run the demo benchmark (no download) and write its HTML report"),
    "realism": ("tap_bench.cli.realism",
                "score simulated traffic against the log (WOSAC 2025 realism, by manoeuvre)"),
    "view": ("tap_bench.cli.view",
             "replay episodes: two policies side by side, with their labels"),
    # similarity: SDL search, unique behaviours, the paper's ADE / DTW experiments
    "search": ("tap_bench.cli.search",
               "find trajectories (or scenarios) with similar SDL labels"),
    "unique": ("tap_bench.cli.unique", "list the unique behaviours of a label table"),
    "export": ("tap_bench.cli.export",
               "export labels (every axis, with times and track ids) as OpenLABEL"),
    "evaluate": ("tap_bench.cli.evaluate",
                 "SDL search against ADE and DTW nearest neighbours, unique labels"),
}


def _command(argv: Sequence[str]) -> str | None:
    """The sub-command ``argv`` names: its first argument that is not an option (the
    top-level options, --help and --version, take no value)."""
    first = next((a for a in argv if not a.startswith("-")), None)
    return first if first in COMMANDS else None


def _plugins(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """``argv`` without its ``--plugin MODULE`` options (anywhere: before or after the
    command), and the modules they name, in order."""
    rest: list[str] = []
    plugins: list[str] = []
    args = iter(argv)
    for arg in args:
        if arg == "--":
            rest += [arg, *args]
            break
        if arg == "--plugin":
            value = next(args, None)
            if value is None:
                from tap_bench.errors import ParameterError

                raise ParameterError("--plugin", None, "a module name (--plugin MODULE)")
            plugins.append(value)
        elif arg.startswith("--plugin="):
            plugins.append(arg.partition("=")[2])
        else:
            rest.append(arg)
    return rest, plugins


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The ``tap-bench`` parser: the full parser of the command ``argv`` names, one help
    line for every other command (None: the full parser of every command)."""
    from tap_bench._version import __version__

    parser = argparse.ArgumentParser(
        prog="tap-bench",
        description="Scenario benchmark toolkit: TAP (Trajectory-to-Action Pipeline) labels "
        "driving behaviour as Scenario Description Language (SDL) labels.",
    )
    parser.add_argument("--version", action="version", version=f"tap-bench {__version__}")
    parser.add_argument("--plugin", action="append", default=[], metavar="MODULE",
                        help="import MODULE first: it registers your own measures, data "
                        "formats or policy kinds (repeatable; also after the command; every "
                        "worker process imports it too)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    chosen = _command(argv) if argv is not None else None
    for name, (module, help_line) in COMMANDS.items():
        if argv is None or name == chosen:
            importlib.import_module(module).add_parser(sub)
        else:
            sub.add_parser(name, help=help_line)
    return parser


def _terminate(signum: int, frame: object) -> None:
    """SIGTERM ends a command as Ctrl-C does: cleanup runs, workers stop, nothing partial
    is left (outputs are written atomically)."""
    raise KeyboardInterrupt


_FULL_OR_READ_ONLY = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS}
"""Errors of the place written to, not of the input or the code: one message, exit 2."""


def _one_line_warning(message: Warning | str, category: type[Warning], filename: str,
                      lineno: int, line: str | None = None) -> str:
    """A warning as the command line shows it: one line, its kind and message, without the
    source line of tap-bench's code that raised it (that is for developers, not users)."""
    return f"tap-bench: {category.__name__}: {message}\n"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``tap-bench``; returns the process exit code.

    Exit codes: 0 success, 1 the command ran but its check failed (a regression), 2 a
    usage or input error, or nothing to show (every :class:`TapBenchError`, printed as one
    message, such as every episode of a rollout failing), 130 interrupted (Ctrl-C or
    SIGTERM).

    Without ``argv`` (the process's program: the ``tap-bench`` script, ``python -m
    tap_bench``), the arguments are ``sys.argv[1:]`` and what the start-up made is kept out
    of later garbage collections after the first task (:func:`tap_bench.execution.
    freeze_start_up`); with ``argv`` (a caller in its own process) nothing is frozen.
    """
    from tap_bench.execution import freeze_start_up, idle_threads_sleep, keep_freed_memory

    if argv is None:  # the process's program: its start-up's objects frozen after a task
        freeze_start_up()
    argv = sys.argv[1:] if argv is None else list(argv)
    keep_freed_memory()  # no page faults for every temporary column
    idle_threads_sleep()  # before NumPy's import: no BLAS thread spinning for nothing
    try:
        argv, plugins = _plugins(argv)
        if plugins:  # before the parsers are built: --format choices come from the registry
            from tap_bench.plugins import load_plugins

            load_plugins(plugins)
    except TapBenchError as err:
        print(f"tap-bench: error: {err}", file=sys.stderr)
        return 2
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    args.plugin = list(plugins)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    previous, formatter = None, warnings.formatwarning
    warnings.formatwarning = _one_line_warning
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
    except OSError as err:
        if err.errno not in _FULL_OR_READ_ONLY:
            raise
        where = f" writing {err.filename}" if err.filename else ""
        print(f"tap-bench {args.command}: error: {os.strerror(err.errno).lower()}{where}; "
              "nothing partial was left (outputs are written atomically). Free some space, "
              "or write to another place (-o).", file=sys.stderr)
        return 2
    finally:
        warnings.formatwarning = formatter
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
