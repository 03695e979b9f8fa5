"""Gymnasium ids for the scenario suite: ``tap_bench/<name>-v<version>``.

:func:`register_suite` runs when both tap-bench and Gymnasium are imported
(:func:`register_on_import`, called by ``import tap_bench``): at once when Gymnasium already
is, else the moment Gymnasium's import finishes, so ``import tap_bench`` does not import
Gymnasium and NumPy (a run served from the cache never needs them) and
``gymnasium.make("tap_bench/highway-v0")`` works in either order of the imports. It reads
only the name and version of each file in ``envs/`` (it never imports highway-env); the file
is fully validated when an environment is made.
"""

from __future__ import annotations

import json
import os
import sys
import types
import warnings
from pathlib import Path
from typing import Any

from tap_bench import catalogue
from tap_bench.errors import CatalogueError, SuiteError
from tap_bench.importhooks import AroundImport

__all__ = ["ENTRY_POINT", "WOMD_ENV_ID", "register_on_import", "register_scenario",
           "register_suite", "registered_ids"]

ENTRY_POINT = "tap_bench.sim.scenario_env:make_env"
WOMD_ENV_ID = "tap_bench/womd-v0"
"""Recorded WOMD scenes in closed loop: ``gymnasium.make(WOMD_ENV_ID, files=[...],
traffic="log" | "idm", ego="sdc")`` (:func:`tap_bench.sim.womd_env.make_womd_env`)."""


def register_scenario(path: str | os.PathLike) -> str:
    """Register a scenario file under ``tap_bench/<name>-v<version>``; return the id.

    Registering the same file again is a no-op; another file under an id already taken is
    an error (Gymnasium ids are global to the process).
    """
    import gymnasium as gym

    path = Path(path).resolve()
    doc = json.loads(path.read_text())
    env_id = f"tap_bench/{doc['name']}-v{int(doc['version'])}"
    existing = gym.registry.get(env_id)
    if existing is not None:
        if Path(str(existing.kwargs.get("scenario"))).resolve() == path:
            return env_id
        raise SuiteError(f"{path}: the id {env_id} is already registered for "
                         f"{existing.kwargs.get('scenario')}; rename the scenario or bump its "
                         "version.")
    gym.register(id=env_id, entry_point=ENTRY_POINT, kwargs={"scenario": str(path)})
    return env_id


def register_suite(folder: str | os.PathLike | None = None) -> list[str]:
    """Register every scenario file in ``folder`` (default: the suite's ``envs/``).

    A file that cannot be read is skipped with a warning naming it, so that one broken file
    does not break ``import tap_bench``; making its env reports the full error.
    """
    import gymnasium as gym

    if folder:
        paths = sorted(Path(folder).glob("*.json"))
    else:
        try:
            paths = list(catalogue.files("envs").values())
        except CatalogueError as err:  # import tap_bench still works; using an env says why
            warnings.warn(str(err), stacklevel=2)
            return []
    if WOMD_ENV_ID not in gym.registry:
        gym.register(id=WOMD_ENV_ID, entry_point="tap_bench.sim.womd_env:make_womd_env")
    ids = []
    for path in paths:
        try:
            ids.append(register_scenario(path))
        except (OSError, ValueError, KeyError, TypeError) as err:
            warnings.warn(f"{path}: scenario not registered: {err}", stacklevel=2)
    return ids


def registered_ids() -> list[str]:
    """The ids of the synthetic scenarios in Gymnasium's registry (``tap_bench/womd-v0``,
    which needs files to drive in, is :data:`WOMD_ENV_ID`)."""
    import gymnasium as gym

    return sorted(k for k in gym.registry if k.startswith("tap_bench/") and k != WOMD_ENV_ID)


class _OnGymnasiumImport(AroundImport):
    """Imports ``gymnasium`` as its own finder and loader would, then registers the suite
    (:func:`register_suite`) and steps aside: the module's loader is Gymnasium's own again
    and this finder leaves ``sys.meta_path``. An import that fails leaves it in place for
    the next attempt.

    It never changes the list ``sys.meta_path`` in place (see :mod:`tap_bench.importhooks`)."""

    target = "gymnasium"

    def exec_module(self, module: types.ModuleType) -> None:
        self.real.exec_module(module)
        self.step_aside(module)
        try:
            register_suite()
        except Exception as err:  # never break `import gymnasium`; making an env says why
            warnings.warn(f"tap-bench's Gymnasium ids were not registered: {err!r}",
                          stacklevel=2)


def register_on_import() -> None:
    """Register the suite's ids (:func:`register_suite`) now if Gymnasium is imported, else
    as soon as it is (``import tap_bench`` calls this)."""
    if sys.modules.get("gymnasium") is not None:
        register_suite()
    elif not any(_is_hook(f) for f in sys.meta_path):  # (also while its import is
        # blocked, None in sys.modules: `import tap_bench` needs no Gymnasium)
        sys.meta_path.insert(0, _OnGymnasiumImport())


def _is_hook(finder: Any) -> bool:
    """Whether ``finder`` is an :class:`_OnGymnasiumImport`, also of this module before an
    ``importlib.reload`` (a second hook would become Gymnasium's loader)."""
    kind = type(finder)
    return (kind.__qualname__ == _OnGymnasiumImport.__qualname__
        and kind.__module__ == __name__)
