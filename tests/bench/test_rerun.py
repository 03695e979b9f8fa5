"""Re-runs that redo nothing (issue 24 section 3): each episode's labels and measures are
kept beside it in the cache, keyed by the episode, the thresholds, the level and the code
of labelling and measures; a re-run reads them and only scores. The results are
bit-identical whatever the cache holds, the batch size and the number of workers: every
table of a cold run equals the re-run's, floats compared with ``==``."""

from __future__ import annotations

import json
import shutil
import sys
import warnings

import pandas as pd
import pytest

from tap_bench.bench.cache import EpisodeCache, label_code
from tap_bench.bench.run import tasks as run_tasks
from tap_bench.bench.run.runner import run_suite
from tap_bench.bench.suite import suite_from_dict
from tap_bench.execution import LocalBackend

from .conftest import without_runs

TABLES = ("episodes", "labels", "segments", "trajectories")


def tiny(thresholds="paper"):
    """One env, two policies, three seeds: 6 episodes of 4 s (what is kept and read per
    episode does not depend on how many envs the run has)."""
    return suite_from_dict({"name": "tiny", "envs": ["highway"],
                            "policies": ["idm", "lane-keeping"], "seeds": "0-2",
                            "reference_policy": "idm", "thresholds": thresholds,
                            "env_overrides": {"highway": {"duration": 4}},
                            "bootstrap": {"n_resamples": 200}}, check_names=False)


_TWO_WORKERS = LocalBackend(2)
"""The module's runs with two workers run on these two worker processes, started by the
first such run and kept until the module ends (``two_workers_kept``), where each run
started its own (about 1.5 CPU s a worker): what is compared here is the tables a run makes
with its episodes spread over two processes, as ``workers=2`` spreads them (``run_suite``
resolves ``workers=2`` to a :class:`LocalBackend` of 2, as this one)."""


@pytest.fixture(scope="module", autouse=True)
def two_workers_kept():
    with _TWO_WORKERS.kept():
        yield


def run(folder, cache, workers=1, suite=None):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run_suite(suite or tiny(), folder, workers=workers, progress=False,
                         report=False, cache=cache,
                         backend=_TWO_WORKERS if workers == 2 else None)


def assert_identical(a, b):
    """Every table of two run results equal, floats with ==."""
    for name in TABLES:
        if (a.folder / f"{name}.parquet").read_bytes() == (
                b.folder / f"{name}.parquet").read_bytes():
            continue  # the same file: the same table
        left = pd.read_parquet(a.folder / f"{name}.parquet")
        right = pd.read_parquet(b.folder / f"{name}.parquet")
        pd.testing.assert_frame_equal(left, right, check_exact=True, obj=name)
        assert left.equals(right), name
    for name, table in a.scores.tables().items():
        other = b.scores.tables()[name]
        pd.testing.assert_frame_equal(table, other, check_exact=True, obj=name)
    assert a.summary["headline"] == b.summary["headline"]


def _episodes_only(source: EpisodeCache, target) -> EpisodeCache:
    shutil.copytree(source.folder, EpisodeCache(target).folder)
    return EpisodeCache(target)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("rerun")
    cache = EpisodeCache(root / "cache")
    cold = run(root / "cold", None)
    first = run(root / "first", cache, workers=2)
    again = run(root / "again", without_runs(cache))
    return root, cold, first, again, cache


def test_a_rerun_reads_labels_and_measures_and_is_identical(runs):
    _, cold, first, again, cache = runs
    assert first.summary["cache"]["simulated"] == 6
    assert first.summary["cache"]["labelled_before"] == 0
    assert again.summary["cache"]["labelled_before"] == 6
    assert again.summary["cache"]["simulated"] == 0
    assert again.summary["timings"]["labelling_cpu_in_workers"] == 0
    assert len(list(cache.labels_folder.glob("*/*.labels"))) == 6
    assert_identical(cold, first)
    assert_identical(cold, again)


def test_a_run_without_its_report_does_not_import_the_report_or_the_viewer(runs, tmp_path,
                                                                         monkeypatch):
    """The report's and the viewer's modules (and through the viewer the map readers and
    numba, about 0.6 CPU s of a child ``bench run --no-report``) are imported only when
    they are written: with them made unimportable, a run without its report still writes
    its folder, the same tables."""
    _, cold, _, _, cache = runs
    for name in ("tap_bench.bench.report.viewer", "tap_bench.bench.report.page"):
        monkeypatch.setitem(sys.modules, name, None)  # an import of it raises ImportError
    result = run(tmp_path / "run", without_runs(cache))
    assert not (result.folder / "report.html").exists()
    assert_identical(cold, result)


FAST_BATCHES = {(1, 1), (5, 2), (30, 1)}
"""(batch, workers) in the fast suite: each batch size once, batches spread over two workers
(5: two uneven batches of 6 episodes; the module's first run simulates with two workers
too), many batches (1) and one batch (30) in one process; the rest of the grid in the slow
suite (1 over two workers starts two more worker processes twice for what 5 over two
covers)."""


@pytest.mark.parametrize(("batch", "workers"), [
    pytest.param(b, w, id=f"{w}-{b}", marks=() if (b, w) in FAST_BATCHES else pytest.mark.slow)
    for w in (1, 2) for b in (1, 5, 30)])
def test_identical_whatever_the_batch_size_and_workers(runs, tmp_path, monkeypatch, batch,
                                                       workers):
    _, cold, _, _, cache = runs
    monkeypatch.setattr(run_tasks, "CACHED_BATCH", batch)
    episodes_only = _episodes_only(cache, tmp_path / "cache")  # labelled again in batches
    result = run(tmp_path / "run", episodes_only, workers=workers)
    assert result.summary["cache"]["cached"] == 6
    assert result.summary["cache"]["labelled_before"] == 0
    assert_identical(cold, result)
    again = run(tmp_path / "again", without_runs(episodes_only), workers=workers)
    assert again.summary["cache"]["labelled_before"] == 6
    assert_identical(cold, again)


def test_identical_whatever_the_cache_holds(runs, tmp_path):
    _, cold, _, _, cache = runs
    mixed = EpisodeCache(tmp_path / "cache")
    shutil.copytree(cache.root, mixed.root)
    without_runs(mixed)
    # each label entry beside its episode's entry (its header names the episode's key), so
    # that what is left does not depend on how the keys sort (they hash tap-bench's code)
    episode_of = {path: json.loads(path.read_bytes().split(b"\n", 1)[0])["doc"]["episode"]
                  for path in mixed.labels_folder.glob("*/*.labels")}
    labels = sorted(episode_of, key=episode_of.get)
    episodes = [mixed.path(episode_of[path]) for path in labels]
    assert len(labels) == 6 and all(path.is_file() for path in episodes)
    for path in labels[::2]:  # half the labels gone
        path.unlink()
    for path in episodes[::3]:  # a third of the episodes gone (one with its labels)
        path.unlink()
    labels[1].write_bytes(labels[1].read_bytes()[:-7])  # one label entry torn
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        result = run(tmp_path / "run", mixed)
    assert 0 < result.summary["cache"]["labelled_before"] < 6
    assert any("label entry" in note for note in result.summary["cache"]["refused"])
    assert_identical(cold, result)


def test_other_thresholds_relabel_but_do_not_resimulate(runs, tmp_path):
    from dataclasses import fields, replace

    from tap_bench.thresholds import PRESETS, save_thresholds

    _, _, _, _, cache = runs
    paper = PRESETS["paper"]
    name = next(f.name for f in fields(paper) if isinstance(getattr(paper, f.name), float))
    other = tmp_path / "other.json"
    save_thresholds(replace(paper, **{name: getattr(paper, name) * 1.5}), other)
    cold = run(tmp_path / "cold", None, suite=tiny(str(other)))
    warm = run(tmp_path / "warm", cache, suite=tiny(str(other)))
    assert warm.summary["cache"]["simulated"] == 0
    assert warm.summary["cache"]["labelled_before"] == 0
    assert_identical(cold, warm)


def test_the_label_key_follows_the_code_of_labels_and_measures(monkeypatch):
    from tap_bench.bench import cache as cache_module
    from tap_bench.bench.measures import MEASURES, Measure

    base = label_code()
    extra = Measure("plugin_test_measure", "m", True, "a plug-in's measure", 1.0,
                    lambda steps: steps.mean(steps.speed))
    MEASURES.register(extra)
    try:
        assert label_code()["measures"] != base["measures"]
    finally:
        MEASURES.unregister("plugin_test_measure")
    assert label_code() == base
    monkeypatch.setattr(cache_module, "LABEL_CODE", ("tap_bench.labelling",))
    assert label_code()["code"] != base["code"]


@pytest.mark.parametrize("start", ["tap_bench.bench.run.tasks", "tap_bench.bench.scores.contexts",
                                   "tap_bench.sim.roads", "tap_bench.sources.maps"])
def test_the_label_key_covers_the_code_that_makes_a_label_entry(start):
    # a label entry holds what run_tasks makes: labels and measures along the episode's map
    # (tap_bench.sim.roads for highway-env, tap_bench.sources.maps for recorded scenes) and
    # the context occurrences (tap_bench.bench.scores.contexts): every module that code imports must
    # be in the label key or in the episode key, or an edit to it (the sampling step of
    # tap_bench.maps, the occurrences' rules) would leave the old entries in the cache
    from tap_bench.bench.cache import LABEL_CODE, _simulation_modules, _tap_bench_closure

    covered = {p.resolve() for p in _tap_bench_closure(LABEL_CODE).values()} \
        | {p.resolve() for p in _simulation_modules()}
    made_by = _tap_bench_closure((start,))
    assert start in made_by
    assert {name for name, path in made_by.items() if path.resolve() not in covered} == set()
