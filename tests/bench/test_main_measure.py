"""A measure registered in a script's ``__main__`` cannot reach a run's workers (issue 22):
the run fails those episodes with the fix (a module named as a plugin), never a missing
column or a KeyError after every episode ran; with one worker (in the script's process) it
works. The script runs once, in one child process: with one worker, then with two."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = textwrap.dedent('''
    import sys
    import warnings

    warnings.filterwarnings("ignore")
    from tap_bench.bench.measures import register_measure
    from tap_bench.bench.run.runner import run_suite
    from tap_bench.bench.suite import suite_from_dict


    @register_measure("main_only", unit="m/s", higher_is_better=True, margin=1.0,
                      description="registered in __main__")
    def main_only(steps):
        return steps.mean(steps.speed)


    if __name__ == "__main__":
        suite = suite_from_dict({"name": "tiny", "envs": ["highway"], "policies": ["idm"],
                                 "seeds": "0-1", "env_overrides": {"highway": {"duration": 2}},
                                 "bootstrap": {"n_resamples": 100}}, check_names=False)
        for folder, workers in zip(sys.argv[1::2], sys.argv[2::2]):
            result = run_suite(suite, folder, workers=int(workers), progress=False,
                               report=False, cache=None)
            print("COLUMN", "main_only" in result.episodes.columns,
                  result.episodes["main_only"].notna().all(), flush=True)
''')


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    """The script run as a user runs it, with one worker (in its process), then with two
    workers: one child process for both runs (about 1.3 CPU s a child), the second run's
    workers started afresh as any run's are."""
    tmp_path = tmp_path_factory.mktemp("main_measure")
    script = tmp_path / "my_run.py"
    script.write_text(SCRIPT)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_WAIT_POLICY": "PASSIVE",
           "TAP_BENCH_CACHE": str(tmp_path / "cache")}
    return tmp_path, subprocess.run(
        [sys.executable, str(script), str(tmp_path / "run1"), "1", str(tmp_path / "run2"),
         "2"], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=600)


def test_a_measure_registered_in_main_fails_a_run_with_workers_with_the_fix(runs):
    tmp_path, done = runs
    assert done.returncode != 0
    assert done.stdout.count("COLUMN") == 1  # the run with one worker only
    err = done.stderr
    assert "EpisodesFailedError" in err and "highway idm seed 0" in err
    assert "measure(s) main_only are registered in the process that started the run but " \
           "not in this worker" in err
    assert "register them in a module (not in __main__)" in err and "--plugin MODULE" in err
    assert "KeyError" not in err
    assert not (tmp_path / "run2" / "summary.json").exists()  # no half-written run


def test_with_one_worker_the_measure_is_scored(runs):
    tmp_path, done = runs
    assert "COLUMN True True" in done.stdout, done.stderr[-2000:]
    assert (tmp_path / "run1" / "summary.json").is_file()
