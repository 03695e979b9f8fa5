"""``bench run`` on tiny suites: the run folder, a failing episode that does not end the
run, atomic writes that never replace a run unless asked, worker processes."""

from __future__ import annotations

import json
import warnings
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.run.runner import RunExistsError, read_run, run_suite
from tap_bench.bench.suite import suite_from_dict
from tap_bench.errors import FileFormatError
from tap_bench.sim.policies import LaneKeepingPolicy, available_policies, register_policy


class FlakyPolicy(LaneKeepingPolicy):
    """Keeps its lane, but raises on seed 1 (an episode that fails mid-run)."""

    def __init__(self) -> None:
        super().__init__(name="flaky-test")

    def reset(self, env, *, seed: int) -> None:
        self._seed = seed
        super().reset(env, seed=seed)

    def act(self, observation):
        if self._seed == 1:
            raise RuntimeError("flaky policy breaks on seed 1")
        return super().act(observation)


if "flaky-test" not in available_policies():
    register_policy("flaky-test", FlakyPolicy, "test policy that fails on seed 1")


def tiny(policies, seeds="0-2", **extra):
    return suite_from_dict({"name": "tiny", "envs": ["merge"], "policies": policies,
                            "seeds": seeds, "env_overrides": {"merge": {"duration": 3}},
                            "bootstrap": {"n_resamples": 200}, **extra}, check_names=False)


@pytest.fixture(scope="module")
def flaky_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "run-001"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run_suite(tiny(["lane-keeping", "flaky-test"]), out, workers=1, progress=False)


def test_run_folder_holds_tables_summary_plots_and_report(flaky_run):
    folder = flaky_run.folder
    for name in ("episodes", "labels", "trajectories", "label_counts", "measures", "paired",
                 "paired_measures", "paired_labels", "coverage", "novelty"):
        assert (folder / f"{name}.parquet").is_file(), name
    assert (folder / "report.html").is_file()
    assert sorted(p.name for p in (folder / "plots").glob("*.svg"))
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["seeds"] == [0, 1, 2]
    assert summary["level"] == "maneuver"
    assert summary["thresholds"]["thresholds"]["w"] == {"str": 0.0283, "grad": 0.0754,
                                                        "med": 0.1541}
    assert "numpy" in summary["versions"] and summary["suite"]["name"] == "tiny"
    assert {"rollouts_wall", "scoring", "total"} <= set(summary["timings"])
    assert not [p for p in folder.parent.iterdir() if p.name.startswith(".")]


def test_one_failing_episode_is_reported_and_the_rest_scored(flaky_run):
    eps = flaky_run.episodes
    failed = eps[eps["status"] != "ok"]
    assert failed[["policy", "seed"]].values.tolist() == [["flaky-test", 1]]
    assert "breaks on seed 1" in failed["error"].iloc[0]
    assert flaky_run.summary["n_failed"] == 1
    assert flaky_run.summary["failed"][0]["seed"] == 1
    paired = flaky_run.scores.paired.iloc[0]
    assert (paired["n_pairs"], paired["n_dropped"]) == (2, 1)
    # lane keeping on both sides of a pair: the same ego label on every paired seed
    assert paired["agreement"] == 1.0


def test_an_existing_run_is_never_replaced_unless_asked(flaky_run):
    before = (flaky_run.folder / "episodes.parquet").read_bytes()
    with pytest.raises(RunExistsError, match="--overwrite"):
        run_suite(tiny(["lane-keeping"]), flaky_run.folder, workers=1, progress=False)
    assert (flaky_run.folder / "episodes.parquet").read_bytes() == before


def test_read_run(flaky_run, tmp_path):
    summary, episodes = read_run(flaky_run.folder)
    assert summary["run"] == "run-001" and len(episodes) == 6
    with pytest.raises(FileFormatError, match="not a finished run folder"):
        read_run(tmp_path)


@pytest.mark.slow
def test_workers_give_the_same_episodes(tmp_path):
    """Slow: one worker and two give the same episodes. Fast: tests/bench/test_rerun.py::
    test_a_rerun_reads_labels_and_measures_and_is_identical compares every table of a run
    on one worker with one on two workers (floats with ==), as test_run_cache.py::
    test_an_unchanged_rerun_is_served_whole_and_equal does for a run with its report."""
    suite = tiny(["idm", "idm-aggressive"], seeds="0-1")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        one = run_suite(suite, tmp_path / "one", workers=1, progress=False, report=False)
        two = run_suite(suite, tmp_path / "two", workers=2, progress=False, report=False)
    cols = ["env", "policy", "seed", "sdl", "mean_speed", "rms_jerk", "crashed"]
    pd.testing.assert_frame_equal(one.episodes[cols], two.episodes[cols])
    assert np.isfinite(one.episodes["mean_speed"]).all()



def test_the_estimate_s_first_episode_is_labelled_with_its_batch(tmp_path, monkeypatch):
    """The first episode of an env, simulated alone to time the estimate, is labelled and
    measured with the other episodes of its env and policy (one labelling call fewer per
    env), and the run's tables equal a run without an estimate, float for float. In this
    process (one worker) a few episodes of an env and policy are labelled in one call
    (IN_PROCESS_BATCH), where worker processes get tasks of one episode each."""
    import tap_bench.bench.run.tasks as run_tasks

    calls = []
    real = run_tasks._label_together
    monkeypatch.setattr(run_tasks, "_label_together",
                        lambda tasks, got: calls.append(len(tasks)) or real(tasks, got))
    suite = tiny(["idm", "lane-keeping"], seeds="0-3")
    lines: list[str] = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_suite(suite, tmp_path / "timed", workers=1, progress=False, report=False,
                  cache=tmp_path / "c1", announce=lines.append)
        assert any("timing a first episode" in line for line in lines)
        assert sorted(calls) == [4, 4]  # 8 episodes in this process: one batch a policy
        calls.clear()
        run_suite(suite, tmp_path / "plain", workers=1, progress=False, report=False,
                  cache=tmp_path / "c2")
    assert sorted(calls) == [4, 4]
    # on two workers the same 8 episodes are 8 tasks, to keep both workers busy to the end
    stand_ins = [SimpleNamespace(env="merge", policy=policy, scenario=None)
                 for policy in ("idm", "lane-keeping") for _ in range(4)]
    items = run_tasks._items(stand_ins, list(range(8)), [False] * 8, workers=2)
    assert [members for members, _ in items] == [[i] for i in range(8)]
    items = run_tasks._items(stand_ins, list(range(8)), [False] * 8, workers=1)
    assert [members for members, _ in items] == [[0, 1, 2, 3], [4, 5, 6, 7]]
    monkeypatch.setattr(run_tasks, "CACHED_BATCH", 3)  # still the most a task holds
    items = run_tasks._items(stand_ins, list(range(8)), [False] * 8, workers=1)
    assert [members for members, _ in items] == [[0, 1, 2], [3], [4, 5, 6], [7]]
    for name in ("episodes", "labels", "segments"):
        pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "timed" / f"{name}.parquet"),
                                      pd.read_parquet(tmp_path / "plain" / f"{name}.parquet"),
                                      check_exact=True, obj=name)


def test_a_named_label_table_is_a_reference(tmp_path):
    from tap_bench.labelling import label
    from tap_bench.sim.rollout import rollout

    trajectories, _ = rollout("merge", "idm", [5, 6], duration=3, progress=False)
    mine = label(trajectories, level="maneuver")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_suite(tiny(["idm", "lane-keeping"]), tmp_path / "run", workers=1,
                           progress=False, report=False, references={"my corpus": mine})
    assert "my corpus" in set(result.scores.coverage["reference"])
    assert result.summary["references"] == {"my corpus": f"a label table of {len(mine)} rows"}


@pytest.mark.parametrize("env", [
    "highway",  # crashes and lane changes: the fast suite's case
    # the same batching of the same tables on other roads (3.5 CPU s each): slow
    pytest.param("merge", marks=pytest.mark.slow),
    pytest.param("roundabout", marks=pytest.mark.slow)])
def test_a_batch_labels_and_measures_each_episode_as_it_does_alone(env):
    """The runner labels and measures the episodes of one env and policy as one table: each
    episode's labels, segments and measures equal, float for float, those of the episode
    alone, whatever the batch holds and in whatever order (crashes and lane changes
    included: the random policy crashes, IDM changes lanes)."""
    from tap_bench.bench.run.plan import _tasks, plan_suite
    from tap_bench.bench.run.tasks import _Batch, _run_batch, _run_task

    suite = suite_from_dict({"name": "batch", "envs": [env], "policies": ["idm", "random"],
                             "seeds": "0-3", "env_overrides": {env: {"duration": 10}}},
                            check_names=False)
    tasks = _tasks(plan_suite(suite), True, None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        alone = [_run_task(task) for task in tasks]
        rng = np.random.default_rng(len(env))
        batches = []
        for policy in ("idm", "random"):
            members = [i for i, task in enumerate(tasks) if task.policy == policy]
            batches.append(members)  # the whole group, in order
            batches.append(list(rng.permutation(members)[:3]))  # some of it, shuffled
        for members in batches:
            together = _run_batch(_Batch(tuple(tasks[i] for i in members)))
            for i, result in zip(members, together, strict=True):
                for name in ("episodes", "labels", "segments", "trajectories"):
                    pd.testing.assert_frame_equal(result[name], alone[i][name],
                                                  check_exact=True, obj=f"{name} of {i}")
    crashed = pd.concat([r["episodes"] for r in alone])["crashed"]
    assert not crashed.all()
    if env == "highway":  # a crash is compared too
        assert crashed.any()
    assert all(len(r["labels"]) for r in alone)
