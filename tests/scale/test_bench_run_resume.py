"""``tap-bench bench run`` on recorded scenes killed outright (SIGKILL, after a seeded
number of episodes) and run again with the same command and ``--cache``: the episodes the killed run
finished are read from the cache, the run says how many ("N read, M simulated"), and the
run folder's tables equal those of a run never interrupted, float for float (the same code
ran)."""

from __future__ import annotations

import json
import random
import re
import warnings
from pathlib import Path

import pandas as pd
import pytest
from kill_points import run_killed
from scale_scenes import scene_files

from tap_bench.cli import main

PROJECT_ROOT = Path(__file__).resolve().parents[2]
DATA = PROJECT_ROOT.parent / "shared" / "data"


def _suite(path: Path, files: list[str], seeds: str) -> Path:
    path.write_text(json.dumps({
        "name": "womd-resume", "version": 0,
        "envs": [{"womd": files, "traffic": "log", "ego": "sdc", "policy_frequency": 2}],
        "policies": ["log", "idm"], "reference_policy": "log", "seeds": seeds,
        "level": "maneuver", "thresholds": "paper",
        "bootstrap": {"n_resamples": 200, "level": 0.95, "seed": 0}}))
    return path


def _args(suite: Path, out: Path, cache: Path) -> list[str]:
    return ["bench", "run", "--suite", str(suite), "-o", str(out), "--cache", str(cache),
            "--workers", "1", "--no-progress", "--no-report"]


def _cached(cache: Path) -> int:
    """The episodes stored in the cache so far (whole entries: each is renamed in place)."""
    return len(list((cache / "episodes").glob("*/*.episode")))


def _same_tables(a: Path, b: Path) -> None:
    """Run folders ``a`` and ``b`` hold the same tables (the episode table sorted by its
    keys) and the same verdict."""
    names = sorted(p.name for p in a.glob("*.parquet"))
    assert names == sorted(p.name for p in b.glob("*.parquet"))
    assert {"episodes.parquet", "trajectories.parquet", "labels.parquet"} <= set(names)
    for name in names:
        x, y = pd.read_parquet(a / name), pd.read_parquet(b / name)
        if name == "episodes.parquet":
            x, y = (t.sort_values(["env", "policy", "seed"], ignore_index=True)
                    for t in (x, y))
        pd.testing.assert_frame_equal(x, y, check_exact=True, obj=name)
    sa, sb = (json.loads((f / "summary.json").read_text()) for f in (a, b))
    for key in ("headline", "verdict", "n_episodes", "failed", "methods"):
        assert sa[key] == sb[key], key


def _kill_and_resume(tmp_path: Path, capsys, suite: Path, n_episodes: int,
                     kill_points: int, seed: int) -> list[int]:
    """Run ``suite`` whole, then ``kill_points`` times: start it into a fresh folder and
    cache, SIGKILL it just after it stored a drawn number of episodes in the cache, at
    least one (kill_points: by progress, so mid-run on any machine; the next episode not
    begun), run the same command again (in this process) and compare; the episodes each
    killed run had finished."""
    whole = tmp_path / "whole"
    with warnings.catch_warnings():  # in this process: the same code as the children's
        warnings.simplefilter("ignore")
        assert main(_args(suite, whole, tmp_path / "cache-whole")) == 0
    rng = random.Random(seed)
    targets = sorted(rng.randint(1, n_episodes - 1) for _ in range(kill_points))
    done_before = []
    for trial, target in enumerate(targets):
        out, cache = tmp_path / f"t{trial}" / "run", tmp_path / f"t{trial}" / "cache"
        run_killed(_args(suite, out, cache), "tap_bench.bench.cache:EpisodeCache.put",
                   "after", target, cwd=suite.parent)
        done = _cached(cache)
        assert not out.exists() and done == target, (target, done)
        capsys.readouterr()
        with warnings.catch_warnings():  # the same command again, in this process
            warnings.simplefilter("ignore")
            code = main(_args(suite, out, cache))
        stdout = capsys.readouterr().out
        assert code == 0, stdout[-3000:]
        said = re.search(r"episode cache .*: (\d+) read, (\d+) simulated", stdout)
        assert said, stdout
        assert (int(said[1]), int(said[2])) == (done, n_episodes - done), stdout
        _same_tables(out, whole)
        # the killed run's spill is removed (its process is gone); only folders of tap-bench
        # beside the run: the run, the cache, and a killed run's unfinished output if any
        left = sorted(p.name for p in out.parent.iterdir())
        assert left[-2:] == ["cache", "run"], left
        assert all(n.startswith(".run.") and n.endswith(".tmp") for n in left[:-2]), left
        done_before.append(done)
    return done_before


def test_a_killed_bench_run_resumes_from_the_cache_to_the_same_tables(tmp_path, capsys):
    files = scene_files(tmp_path / "scenes", 1, per_file=1)
    suite = _suite(tmp_path / "suite.json", files, "all")
    # killed as soon as the first episode is in the cache: the second not yet run
    assert _kill_and_resume(tmp_path, capsys, suite, 2, kill_points=1, seed=37) == [1]


@pytest.mark.slow
def test_a_killed_bench_run_of_real_scenes_resumes_to_the_same_tables(tmp_path, capsys):
    if not (DATA / "womd" / "motion_data_one_scenario.tfrecord").is_file():
        pytest.skip(f"real WOMD samples not found in {DATA / 'womd'}")
    files = [str(DATA / "womd" / "*.tfrecord"), str(DATA / "womd-dev" / "*.tfrecord")]
    suite = _suite(tmp_path / "suite.json", files, "0-3")
    done = _kill_and_resume(tmp_path, capsys, suite, 8, kill_points=3, seed=2026)
    assert all(d > 0 for d in done), done  # every run resumed some episodes
