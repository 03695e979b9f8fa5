"""Where the benchmark's data lives: the catalogue of scenario, policy and suite files.

The benchmark is data (SPEC section 6): one JSON file per scenario in ``envs/``, one per
policy in ``policies/`` (with the trained models), one per suite in ``envs/suites/``. This
module finds those files, from these folders, first match wins:

1. every folder of ``$TAP_BENCH_PATH`` (``os.pathsep``-separated), for your own scenarios,
   policies and suites beside the built-in ones (a file of the same name overrides one);
2. ``$TAP_BENCH_SUITE``, a folder that *replaces* the built-in suite when set;
3. the built-in suite: ``tap_bench/_catalogue/`` in an installed wheel (``envs/`` and
   ``policies/`` are copied there at build time), or the ``envs/`` and ``policies/`` folders
   at the top of a source checkout (an editable install).

Each folder may hold ``envs/``, ``policies/``, ``envs/suites/`` and ``results/baselines/``
(the gate's baselines, one per suite: ``default.json``); a missing one is skipped. When
no built-in folder can be found at all, :func:`folders` raises
:class:`~tap_bench.errors.CatalogueError` naming where it looked and the fix, rather than
listing nothing.
"""

from __future__ import annotations

import os
from pathlib import Path

from tap_bench.errors import CatalogueError, did_you_mean

__all__ = ["CACHE_VARIABLE", "KINDS", "PATH_VARIABLE", "REPLACE_VARIABLE", "builtin_root",
           "cache_dir", "files", "find", "folders"]

KINDS = {"envs": "envs", "policies": "policies", "suites": os.path.join("envs", "suites"),
         "baselines": os.path.join("results", "baselines")}
"""Kind of file -> its folder under a catalogue root (``baselines``: the regression gate's
baselines, one per suite, named after it)."""
PATH_VARIABLE = "TAP_BENCH_PATH"
"""Environment variable: more catalogue roots, searched first."""
REPLACE_VARIABLE = "TAP_BENCH_SUITE"
"""Environment variable: a catalogue root that replaces the built-in one."""
CACHE_VARIABLE = "TAP_BENCH_CACHE"
"""Environment variable: the folder of tap-bench's caches."""

_PACKAGE = Path(__file__).resolve().parent


def builtin_root() -> Path:
    """The built-in catalogue root: the wheel's copy, else the source checkout's top level.

    Raises:
        CatalogueError: neither holds ``envs/`` (a broken installation).
    """
    candidates = [_PACKAGE / "_catalogue", _PACKAGE.parent]
    for root in candidates:
        if (root / "envs").is_dir() and (root / "policies").is_dir():
            return root
    raise CatalogueError(
        "the built-in scenarios and policies are missing: looked for envs/ and policies/ in "
        + " and ".join(str(c) for c in candidates) + ". Reinstall tap-bench (pip install "
        "tap-bench, or pip install -e . from a checkout), or point $TAP_BENCH_SUITE to a "
        "folder holding envs/ and policies/.")


def roots() -> list[Path]:
    """The catalogue roots in search order (see the module docstring)."""
    out = [Path(p).expanduser() for p in os.environ.get(PATH_VARIABLE, "").split(os.pathsep)
           if p]
    replace = os.environ.get(REPLACE_VARIABLE)
    out.append(Path(replace).expanduser() if replace else builtin_root())
    return out


def folders(kind: str) -> list[Path]:
    """The existing folders of ``kind`` (``envs``, ``policies``, ``suites``), in search order."""
    if kind not in KINDS:
        raise did_you_mean("catalogue kind", kind, KINDS)
    return [root / KINDS[kind] for root in roots() if (root / KINDS[kind]).is_dir()]


def files(kind: str, suffix: str = ".json") -> dict[str, Path]:
    """Every file of ``kind`` by name (its stem), the first folder's file winning a tie."""
    out: dict[str, Path] = {}
    for folder in folders(kind):
        for path in sorted(folder.glob(f"*{suffix}")):
            out.setdefault(path.stem, path)
    return out


def find(kind: str, name: str, suffix: str = ".json") -> Path | None:
    """The file of ``kind`` called ``name``, or None."""
    return files(kind, suffix).get(name)


def cache_dir() -> Path:
    """Where tap-bench keeps what it can rebuild (episodes of ``bench run``, what highway-env
    accepts): ``$TAP_BENCH_CACHE``, else ``$XDG_CACHE_HOME/tap-bench``, else
    ``~/.cache/tap-bench``. Deleting it costs only time."""
    if os.environ.get(CACHE_VARIABLE):
        return Path(os.environ[CACHE_VARIABLE]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join("~", ".cache")
    return Path(base).expanduser() / "tap-bench"
