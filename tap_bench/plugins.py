"""Plugins: the modules that register a user's measures, data formats and policy kinds.

A registration (:mod:`tap_bench.registry`) lives in the process that made it. A run spreads
over worker processes and Ray workers, so the modules that register entries are named, as
data, wherever a run is described: ``--plugin MODULE`` on the command line (repeatable), and
``"plugins": ["my_measures"]`` in a suite file. :func:`load_plugins` imports them; a suite
run imports them before it reads the suite and records them in ``summary.json``; ``bench
check`` imports those of the run it checks. Every worker of :mod:`tap_bench.execution` (local
processes and Ray tasks, for every command) imports the plugins its parent loaded
(:func:`loaded_plugins`) before its first task. Importing a module twice is a no-op
(Python's module cache), so a module imported by hand before a run does no harm.

A plugin is code: it runs with your rights, in every worker. Name only modules you trust,
as you would for a suite's ``import`` policy.
"""

from __future__ import annotations

import importlib
import re
from collections.abc import Iterable

from tap_bench.errors import ParameterError

__all__ = ["ENV_VAR", "load_plugins", "loaded_plugins", "merge_plugins"]

_MODULE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")
ENV_VAR = "TAP_BENCH_PLUGINS"
"""How a local worker process learns the plugins of its parent (module names, comma
separated): :mod:`tap_bench.execution` sets it when it starts a worker."""
_LOADED: dict[str, None] = {}  # the plugins this process imported, in order


def load_plugins(modules: Iterable[str], *, source: str = "--plugin") -> tuple[str, ...]:
    """Import each module of ``modules`` (in order, once per process) and return their names.

    Args:
        modules: dotted module names (``my_package.measures``).
        source: where the names come from, for errors (``--plugin``, ``suite mine``).

    Raises:
        ParameterError: a name is not a module name, or the module cannot be imported (the
            message says the import error and how to make it importable).
    """
    names = tuple(modules)
    for name in names:
        if not isinstance(name, str) or not _MODULE.match(name):
            raise ParameterError(f"{source} plugin", name, "a dotted module name such as "
                                 "'my_package.measures' (not a file path)")
        try:
            importlib.import_module(name)
        except ImportError as err:
            raise ParameterError(f"{source} plugin", name, "an importable module",
                                 hint=f"({type(err).__name__}: {err}) Put its folder on "
                                 "PYTHONPATH or install its package; every worker process "
                                 "imports it too.") from err
        _LOADED.setdefault(name)
    return names


def loaded_plugins() -> tuple[str, ...]:
    """The plugins this process has imported with :func:`load_plugins`, in order: what
    :mod:`tap_bench.execution` has every worker (local or Ray) import before its first
    task."""
    return tuple(_LOADED)


def merge_plugins(*groups: Iterable[str]) -> tuple[str, ...]:
    """The modules of every group, in order, each once."""
    return tuple(dict.fromkeys(name for group in groups for name in group))
