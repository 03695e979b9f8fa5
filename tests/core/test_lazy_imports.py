"""The public API resolves every name although it is imported lazily; ``import tap_bench``,
``tap-bench --help`` and ``tap-bench envs`` stay clear of the heavy dependencies; the
command table agrees with the commands' own parsers."""

from __future__ import annotations

import argparse
import importlib
import json
import subprocess
import sys
import types
from pathlib import Path

import pytest

import tap_bench
import tap_bench.bench
import tap_bench.sim
import tap_bench.similarity
from tap_bench.cli import COMMANDS, build_parser, main

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("package", [tap_bench, tap_bench.bench, tap_bench.sim,
                                     tap_bench.similarity], ids=lambda p: p.__name__)
def test_every_public_name_resolves(package):
    for name in package.__all__:
        value = getattr(package, name)
        assert value is not None and not isinstance(value, types.ModuleType), name
        exec(f"from {package.__name__} import {name}", {})
    assert set(package.__all__) <= set(dir(package))


def test_a_name_that_is_also_a_submodule_stays_the_function():
    import tap_bench.sim.rollout  # sets the package attribute, as any such import does
    from tap_bench.sim import rollout as from_sim

    assert callable(tap_bench.rollout) and callable(tap_bench.sim.rollout)
    assert from_sim is tap_bench.rollout is sys.modules["tap_bench.sim.rollout"].rollout


def test_a_missing_name_is_an_attribute_error_and_subpackages_load():
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        tap_bench.not_a_name  # noqa: B018
    assert tap_bench.bench.Suite is importlib.import_module("tap_bench.bench.suite").Suite


def _fresh(script: str, folder: Path) -> subprocess.CompletedProcess:
    """``script`` run in a fresh interpreter in ``folder`` (tap-bench from this tree, a cache
    of the folder's own, no other environment); fails the test when it fails."""
    return subprocess.run([sys.executable, "-c", script], cwd=folder, check=True,
                          capture_output=True, text=True,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin",
                               "TAP_BENCH_CACHE": str(folder / "cache")})


def _loaded_after(code: str, tmp_path: Path) -> set[str]:
    """Top-level modules loaded by ``code`` in a fresh interpreter."""
    script = (f"import sys\n{code}\nimport json\n"
              "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))")
    out = _fresh(script, tmp_path)
    return set(json.loads(out.stdout.strip().splitlines()[-1]))


HEAVY = {"pandas", "pyarrow", "highway_env", "matplotlib", "numba", "scipy", "torch", "pygame"}


def test_import_and_the_quick_commands_leave_the_heavy_packages_alone(tmp_path):
    # nor Gymnasium and NumPy: the env ids are registered when both are imported, in
    # either order (test_the_env_ids_are_registered_whichever_is_imported_first)
    assert not _loaded_after("import tap_bench", tmp_path) & (HEAVY | {"gymnasium", "numpy"})
    help_modules = _loaded_after(
        "from tap_bench.cli import main\ntry:\n    main(['--help'])\nexcept SystemExit:\n"
        "    pass", tmp_path)
    assert not help_modules & HEAVY  # numpy, yes: gymnasium's, for the env ids
    # the first 'envs' reads highway-env's defaults once; later ones read the cache
    _loaded_after("from tap_bench.cli import main\nmain(['envs'])", tmp_path)
    assert not _loaded_after("from tap_bench.cli import main\nmain(['envs'])", tmp_path) & HEAVY


def test_the_command_table_agrees_with_the_commands():
    full = build_parser()
    actions = next(a for a in full._actions if isinstance(a, argparse._SubParsersAction))
    helps = {c.dest: c.help for c in actions._choices_actions}
    assert helps == {name: help_line for name, (_, help_line) in COMMANDS.items()}
    quick = build_parser(["label", "x"])
    quick_actions = next(a for a in quick._actions
                         if isinstance(a, argparse._SubParsersAction))
    assert list(quick_actions.choices) == list(COMMANDS)


def test_help_lists_every_command_and_a_typo_is_refused(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert all(name in out for name in COMMANDS)
    with pytest.raises(SystemExit) as exit_:
        main(["labl", "x"])
    assert exit_.value.code == 2
    assert "invalid choice: 'labl'" in capsys.readouterr().err


@pytest.fixture(scope="module")
def modules_of_a_worker(tmp_path_factory) -> dict[str, list[str]]:
    """The modules loaded in a fresh interpreter after each of three imports, one after the
    other: the task module a worker of ``bench run`` imports (``tasks``), then the scoring
    (``scoring``), then the ADE / DTW search (``similarity``). One child process for the
    two tests below, which only read it, where they started three."""
    folder = tmp_path_factory.mktemp("imports")
    script = ("import json, sys\nsteps = {}\n"
              "import tap_bench.bench.run.tasks\nsteps['tasks'] = sorted(sys.modules)\n"
              "import tap_bench.bench.scores.scoring\nsteps['scoring'] = sorted(sys.modules)\n"
              "from tap_bench.similarity import ade_nearest\n"
              "steps['similarity'] = sorted(sys.modules)\nprint(json.dumps(steps))")
    out = _fresh(script, folder)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_runners_workers_and_scoring_do_not_load_numba(modules_of_a_worker):
    """A worker of ``bench run`` imports the task module (and through it the scoring): the
    label distances, not the ADE / DTW kernels that need numba."""
    def top(step: str) -> set[str]:
        return {m.split(".")[0] for m in modules_of_a_worker[step]}

    assert "numba" not in top("tasks") | top("scoring")
    assert "numba" in top("similarity")


def test_a_worker_loads_the_task_modules_not_the_runner_gate_or_report(modules_of_a_worker):
    """``tap_bench.bench`` resolves its names lazily: a worker importing the task module
    loads neither the runner, the gate (and its power) nor the report and viewer."""
    loaded = set(modules_of_a_worker["tasks"])
    assert "tap_bench.bench.run.tasks" in loaded
    assert not loaded & {"tap_bench.bench.run.runner", "tap_bench.bench.gate.regression",
                         "tap_bench.bench.gate.power", "tap_bench.bench.report.page",
                         "tap_bench.bench.report.viewer", "tap_bench.bench.scores.scoring"}


_IDS = ("import json, sys\nimport gymnasium as gym\nfrom tap_bench.sim.registration import "
        "_OnGymnasiumImport\n"
        "ids = sorted(k for k in gym.registry if k.startswith('tap_bench/'))\n"
        "assert not any(isinstance(f, _OnGymnasiumImport) for f in sys.meta_path)\n"
        "assert not isinstance(gym.__spec__.loader, _OnGymnasiumImport)\n"
        "assert gym.__loader__ is gym.__spec__.loader\n"
        "print(json.dumps(ids))")


@pytest.mark.parametrize("imports", [
    "import tap_bench\nimport gymnasium",
    "import gymnasium\nimport tap_bench",
    "import tap_bench\nfrom gymnasium.envs.registration import registry",
    "from gymnasium.envs.registration import registry\nimport tap_bench.sim.registration",
    "import tap_bench.sim.registration\nimport gymnasium.envs",
    "import gymnasium\ngymnasium.envs.registration._find_spec('tap_bench:tap_bench/merge-v0')",
], ids=["tap_bench first", "gymnasium first", "registration module after",
        "registration module before", "a submodule of each", "module:id syntax"])
def test_the_env_ids_are_registered_whichever_is_imported_first(imports, tmp_path):
    """``import tap_bench`` imports neither Gymnasium nor NumPy (checked once, in
    test_import_and_the_quick_commands_leave_the_heavy_packages_alone); the suite's ids are
    in Gymnasium's registry as soon as both are imported, in either order, and the import
    hook that registers them steps aside once it has (the module's loader is Gymnasium's
    own)."""
    out = _fresh(f"{imports}\n{_IDS}", tmp_path)
    ids = json.loads(out.stdout.strip().splitlines()[-1])
    from tap_bench.sim.registration import WOMD_ENV_ID, registered_ids

    assert ids == sorted([*registered_ids(), WOMD_ENV_ID]) and "tap_bench/highway-v0" in ids
    assert "Warning" not in out.stderr, out.stderr


def test_an_env_is_made_by_id_after_import_tap_bench_alone(tmp_path):
    script = ("import sys\nimport tap_bench\nassert 'gymnasium' not in sys.modules\n"
              "import gymnasium as gym\nenv = gym.make('tap_bench/merge-v0')\n"
              "obs, info = env.reset(seed=0)\nprint(type(env.unwrapped).__name__)")
    out = _fresh(script, tmp_path)
    assert out.stdout.strip().splitlines()[-1] == "MergeEnv"


@pytest.mark.parametrize("before", [
    "import importlib, tap_bench, tap_bench.sim.registration as r\n"
    "importlib.reload(r)\nimportlib.reload(tap_bench)",
    "sys.modules['gymnasium'] = None\nimport tap_bench\ndel sys.modules['gymnasium']",
], ids=["registration module reloaded", "gymnasium blocked at first"])
def test_the_hook_registers_once_and_steps_aside_after_a_reload_or_a_blocked_import(
        before, tmp_path):
    """A reload of the registration module (IPython's autoreload) leaves one hook, not a
    second that would stay Gymnasium's loader (``pkgutil.get_data`` then finds nothing);
    ``import tap_bench`` works while Gymnasium's import is blocked (None in
    ``sys.modules``), and registers the ids once it is not (review5)."""
    script = (f"import sys\n{before}\n"
              "import gymnasium as gym, importlib.machinery, pkgutil\n"
              "assert type(gym.__loader__) is importlib.machinery.SourceFileLoader\n"
              "assert pkgutil.get_data('gymnasium', '__init__.py')\n"
              "assert not any('OnGymnasium' in type(f).__name__ for f in sys.meta_path)\n"
              "import json\nprint(json.dumps(sorted(gym.registry)))")
    out = _fresh(script, tmp_path)
    assert "tap_bench/highway-v0" in json.loads(out.stdout.strip().splitlines()[-1])


_WALK = """
import importlib.abc, importlib.machinery, sys
import {package}

class Imports(importlib.abc.MetaPathFinder):  # the import finishes during another's walk
    def find_spec(self, name, path=None, target=None):
        if name == "probe_mod":
            import {imported}
        return None

class Finds(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    def find_spec(self, name, path=None, target=None):
        return importlib.machinery.ModuleSpec(name, self) if name == "probe_mod" else None
    def create_module(self, spec):
        return None
    def exec_module(self, module):
        module.found = True

at = next(i for i, f in enumerate(sys.meta_path) if type(f).__name__ == "{hook}")
sys.meta_path[at + 1:at + 1] = [Imports(), Finds()]
import probe_mod
assert probe_mod.found and "{imported}" in sys.modules
assert not any(type(f).__name__ == "{hook}" for f in sys.meta_path)
"""


@pytest.mark.parametrize(("package", "imported", "hook"), [
    ("tap_bench", "gymnasium", "_OnGymnasiumImport"),
    ("tap_bench.sim", "highway_env", "_HighwayEnvImport"),
])
def test_an_import_hook_stepping_aside_skips_no_finder_of_a_walk_under_way(
        package, imported, hook, tmp_path):
    """The import system walks the list sys.meta_path while another import (another
    thread's, or one a finder makes) may finish: a hook that removed itself from that list
    in place shifted it under the walk, which then skipped the next finder and reported an
    installed module missing (review5)."""
    script = _WALK.format(package=package, imported=imported, hook=hook)
    _fresh(script, tmp_path)


def test_highway_env_keeps_its_own_loader_after_the_hook(tmp_path):
    """highway-env imported through sim's hook (matplotlib stood in for) has its own loader
    afterwards, as Gymnasium has after registration's hook: the hook stayed its loader, so
    pkgutil.get_data('highway_env', ...) gave None and importlib.resources.files listed
    nothing (review5)."""
    script = ("import importlib.machinery, importlib.resources, pkgutil, sys\n"
              "import tap_bench.sim\nimport highway_env\n"
              "assert type(highway_env.__loader__) is importlib.machinery.SourceFileLoader\n"
              "assert highway_env.__spec__.loader is highway_env.__loader__\n"
              "assert pkgutil.get_data('highway_env', '__init__.py')\n"
              "assert any(p.name == 'envs' for p in "
              "importlib.resources.files('highway_env').iterdir())\n")
    _fresh(script, tmp_path)
