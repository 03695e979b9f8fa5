"""A process that simulates loads what simulating needs: highway-env without matplotlib
(highway-env imports pyplot for one plotting helper, which gets it on first use), and
neither torch nor numba."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _run(code: str, tmp_path: Path) -> dict:
    """The JSON that ``code`` prints last, run in a fresh interpreter."""
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, check=True,
                         capture_output=True, text=True,
                         env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin",
                              "TAP_BENCH_CACHE": str(tmp_path / "cache"),
                              "MPLBACKEND": "Agg"})
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_an_episode_is_simulated_without_matplotlib_torch_or_numba(tmp_path):
    loaded = _run(
        "import sys, json, warnings\nwarnings.simplefilter('ignore')\n"
        "import tap_bench.bench.run.tasks\n"
        "from tap_bench.sim.rollout import resolve_policy, rollout_episode\n"
        "from tap_bench.sim.scenario_env import get_scenario\n"
        "for name in ('highway', 'merge', 'roundabout'):\n"
        "    table, row = rollout_episode(get_scenario(name).with_overrides(duration=1),"
        " resolve_policy('idm'), 0)\n"
        "    assert row['status'] == 'ok' and len(table), row\n"
        "print(json.dumps(sorted({m.split('.')[0] for m in sys.modules})))", tmp_path)
    assert "highway_env" in loaded
    assert not {"matplotlib", "torch", "numba", "stable_baselines3"} & set(loaded)


def test_highway_envs_plotting_helper_gets_pyplot_on_first_use(tmp_path):
    """Two uses after ``import tap_bench.sim`` and highway-env's dynamics module, each in a
    process of its own: one child imports them and forks (os.fork: the two go on from the
    same modules, as two fresh interpreters that ran the same imports would, one start-up
    and one import of highway-env instead of two, about 1.3 CPU s): a user's import of
    pyplot gets the real module, which the helper then uses; the helper used first imports
    pyplot itself."""
    found, first_use = _run(
        "import json, os, sys\nimport tap_bench.sim\nimport highway_env\n"
        "from highway_env.vehicle import dynamics\n"
        "before = 'matplotlib' in sys.modules\n"
        "read, write = os.pipe()\n"
        "if os.fork() == 0:  # a user's import first: the real module\n"
        "    import matplotlib.pyplot as plt\n"
        "    real = type(plt).__name__ == 'module' and plt.__file__.endswith('pyplot.py')\n"
        "    same = dynamics.plt.subplots is plt.subplots\n"
        "    os.write(write, json.dumps([before, real, same]).encode())\n"
        "    os._exit(0)\n"
        "os.close(write)\n"
        "with os.fdopen(read) as stream:\n"
        "    found = json.loads(stream.read())\n"
        "assert os.wait()[1] == 0\n"
        "figure = dynamics.plt.figure  # the helper first: it imports pyplot itself\n"
        "print(json.dumps([found, [figure is sys.modules['matplotlib.pyplot'].figure,"
        " type(sys.modules['matplotlib']).__name__]]))", tmp_path)
    assert found == [False, True, True]
    assert first_use == [True, "module"]


def test_matplotlib_imported_first_is_left_as_it_is(tmp_path):
    same = _run("import json\nimport matplotlib.pyplot as plt\nimport tap_bench.sim\n"
                "from highway_env.vehicle import dynamics\n"
                "print(json.dumps(dynamics.plt is plt))", tmp_path)
    assert same is True
