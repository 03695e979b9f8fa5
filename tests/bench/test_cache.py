"""The episode cache of ``bench run``: a warm run equals a cold one, a corrupt or foreign
entry is simulated again and never used, keys follow every input, concurrent writers and
pruning leave whole entries."""

from __future__ import annotations

import json
import os
import threading
import warnings
from dataclasses import replace

import pandas as pd
import pytest

from tap_bench.bench.cache import (
    EpisodeCache,
    episode_key,
    parse_size,
    policy_fingerprint,
    scenario_fingerprint,
    simulation_fingerprint,
)
from tap_bench.bench.run.runner import run_suite
from tap_bench.bench.suite import suite_from_dict
from tap_bench.cli import main
from tap_bench.errors import EpisodesFailedError, ParameterError
from tap_bench.sim.policies import (
    LaneKeepingPolicy,
    PolicyDefinition,
    available_policies,
    get_definition,
    register_policy,
)
from tap_bench.sim.rollout import rollout
from tap_bench.sim.scenario_env import get_scenario

from .conftest import without_runs

TABLES = ("episodes", "labels", "trajectories")


class AlwaysFails(LaneKeepingPolicy):
    """Raises at its first decision, on every seed."""

    def __init__(self) -> None:
        super().__init__(name="always-fails-test")

    def act(self, observation):
        raise RuntimeError("this policy always fails")


if "always-fails-test" not in available_policies():
    register_policy("always-fails-test", AlwaysFails, "test policy that always fails")


def tiny(policies=("idm", "lane-keeping"), seeds="0-1"):
    return suite_from_dict({"name": "tiny", "envs": ["merge"], "policies": list(policies),
                            "seeds": seeds, "env_overrides": {"merge": {"duration": 3}},
                            "bootstrap": {"n_resamples": 200}}, check_names=False)


def run(suite, folder, cache, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run_suite(suite, folder, workers=1, progress=False, report=False, cache=cache,
                         **kwargs)


def assert_same_results(a, b):
    for name in TABLES:
        if (a.folder / f"{name}.parquet").read_bytes() == (
                b.folder / f"{name}.parquet").read_bytes():
            continue  # the same file: the same table
        pd.testing.assert_frame_equal(pd.read_parquet(a.folder / f"{name}.parquet"),
                                      pd.read_parquet(b.folder / f"{name}.parquet"))
    for name, table in a.scores.tables().items():
        pd.testing.assert_frame_equal(table, b.scores.tables()[name], obj=name)
    assert a.summary["headline"] == b.summary["headline"]


@pytest.fixture(scope="module")
def cold_and_warm(tmp_path_factory):
    """The same suite without a cache, with an empty cache, and again with the filled one."""
    root = tmp_path_factory.mktemp("cache")
    cache = EpisodeCache(root / "cache")
    cold = run(tiny(), root / "cold", None)
    first = run(tiny(), root / "first", cache)
    warm = run(tiny(), root / "warm", cache)
    return cold, first, warm, cache


def test_a_warm_run_reads_every_episode_and_equals_a_cold_run(cold_and_warm):
    cold, first, warm, cache = cold_and_warm
    assert cold.summary["cache"] is None
    assert (first.summary["cache"]["cached"], first.summary["cache"]["simulated"]) == (0, 4)
    assert (warm.summary["cache"]["cached"], warm.summary["cache"]["simulated"]) == (4, 0)
    assert cache.size()[0] == 4
    assert_same_results(cold, first)
    assert_same_results(cold, warm)


def test_a_corrupt_entry_is_simulated_again_never_used(cold_and_warm, tmp_path):
    cold, _, _, cache = cold_and_warm
    entries = sorted(cache.folder.glob("*/*.episode"))
    data = bytearray(entries[0].read_bytes())
    data[-100] ^= 0xFF  # one flipped bit pattern in the Parquet payload
    entries[0].write_bytes(bytes(data))
    entries[1].write_bytes(entries[1].read_bytes()[:500])  # a torn write
    again = run(tiny(), tmp_path / "again", without_runs(cache))
    assert (again.summary["cache"]["cached"], again.summary["cache"]["simulated"]) == (2, 2)
    assert_same_results(cold, again)
    key = entries[0].stem
    assert cache.get(key) is not None  # stored again, whole


def test_an_entry_under_another_key_is_refused(cold_and_warm):
    _, _, _, cache = cold_and_warm
    first, second = sorted(cache.folder.glob("*/*.episode"))[:2]
    foreign = cache.path("f" * 64)
    foreign.parent.mkdir(parents=True, exist_ok=True)
    foreign.write_bytes(first.read_bytes())
    assert cache.get("f" * 64) is None
    assert not foreign.exists()  # deleted, so the episode is simulated and stored again
    assert cache.get(second.stem) is not None


def test_changing_one_policy_simulates_only_its_episodes(cold_and_warm, tmp_path):
    _, _, _, cache = cold_and_warm
    changed = tmp_path / "policies"
    changed.mkdir()
    idm = json.loads(get_definition("idm").path.read_text())
    idm["params"]["time_wanted"] = 2.0
    (changed / "idm.json").write_text(json.dumps(idm))
    suite = replace(tiny(), policies=(str(changed / "idm.json"), "lane-keeping"))
    result = run(suite, tmp_path / "changed", cache)
    assert (result.summary["cache"]["cached"], result.summary["cache"]["simulated"]) == (2, 2)


def test_the_key_follows_every_input(tmp_path):
    versions = simulation_fingerprint()
    merge = scenario_fingerprint(get_scenario("merge"))
    idm = policy_fingerprint(get_definition("idm"))
    key, doc = episode_key(merge, idm, 0, versions)
    assert key == episode_key(merge, idm, 0, versions)[0]
    assert doc["env"]["config"]["simulation_frequency"] == 10
    shorter = scenario_fingerprint(get_scenario("merge").with_overrides(duration=5))
    other_idm = policy_fingerprint(replace(get_definition("idm"), params={"delta": 5.0}))
    newer = {**versions, "highway-env": "99.0"}
    others = {episode_key(merge, idm, 1, versions)[0], episode_key(shorter, idm, 0, versions)[0],
              episode_key(merge, other_idm, 0, versions)[0],
              episode_key(merge, idm, 0, newer)[0]}
    assert key not in others and len(others) == 4
    # a model file is hashed: same definition, other bytes, another key
    model = tmp_path / "agent.zip"
    model.write_bytes(b"weights v1")
    definition = PolicyDefinition("agent", "sb3", params={"model": "agent.zip"},
                                  path=tmp_path / "agent.json")
    before = policy_fingerprint(definition)
    model.write_bytes(b"weights v2")
    after = policy_fingerprint(definition)
    assert before["files"]["model"] != after["files"]["model"]
    assert set(after["versions"]) == {"stable-baselines3", "torch"}
    # a policy registered in Python has no definition to hash: never cached
    assert policy_fingerprint(PolicyDefinition("mine", "python")) is None


def test_concurrent_writers_leave_one_whole_entry(tmp_path):
    cache = EpisodeCache(tmp_path)
    table, episodes = rollout("merge", "lane-keeping", [3], duration=2, progress=False)
    row = episodes.iloc[0].to_dict()
    key, doc = episode_key({"env": "merge"}, {"policy": "lane-keeping"}, 3, {})
    errors = []

    def write():
        try:
            for _ in range(5):
                cache.put(key, doc, table, row, 1.0)
        except Exception as err:  # pragma: no cover - reported below
            errors.append(err)

    threads = [threading.Thread(target=write) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    entry = cache.get(key)
    pd.testing.assert_frame_equal(entry.trajectories, table.reset_index(drop=True))
    assert entry.row["seed"] == 3
    assert sorted(p.name for p in cache.path(key).parent.iterdir()) == [f"{key}.episode"]
    with pytest.raises(ParameterError, match="SHA-256 of doc"):
        cache.put("0" * 64, doc, table, row, 1.0)


def test_prune_keeps_the_most_recently_used_entries_within_the_bound(tmp_path):
    cache = EpisodeCache(tmp_path)
    table, episodes = rollout("merge", "lane-keeping", [0], duration=2, progress=False)
    row = episodes.iloc[0].to_dict()
    keys = []
    for seed in range(4):
        key, doc = episode_key({}, {}, seed, {})
        cache.put(key, doc, table, {**row, "seed": seed}, 1.0)
        keys.append(key)
    for age, key in enumerate(keys):  # keys[0] newest ... keys[3] oldest
        os.utime(cache.path(key), (1e9 - age * 100, 1e9 - age * 100))
    cache.get(keys[3])  # a hit makes the oldest the most recently used
    size = cache.path(keys[0]).stat().st_size
    report = cache.prune(2 * size)
    assert (report.removed, report.kept) == (2, 2)
    assert [cache.contains(k) for k in keys] == [True, False, False, True]
    assert cache.prune(0).kept == 0 and cache.size() == (0, 0)


def test_parse_size():
    assert parse_size("0") == 0
    assert parse_size("500M") == 500 * 2**20
    assert parse_size("1.5G") == int(1.5 * 2**30)
    assert parse_size("2GiB") == 2 * 2**30
    with pytest.raises(ParameterError, match="--max-size"):
        parse_size("lots")


def test_every_episode_failed_is_an_error_not_an_empty_run(tmp_path, capsys):
    with pytest.raises(EpisodesFailedError, match=r"every one of the 2 episode.*this policy "
                       "always fails"):
        run(tiny(policies=("always-fails-test",)), tmp_path / "run", None)
    assert not (tmp_path / "run").exists()
    with pytest.raises(EpisodesFailedError, match="seed 0: RuntimeError: this policy"):
        rollout("merge", "always-fails-test", [0, 1], duration=2, progress=False)
    code = main(["rollout", "--env", "merge", "--policy", "always-fails-test", "--seeds",
                 "0-1", "--duration", "2", "-o", str(tmp_path / "t.parquet"), "--no-progress"])
    assert code == 2
    assert "every one of 2 episode(s) of always-fails-test on merge failed" in \
        capsys.readouterr().err
    assert not (tmp_path / "t.parquet").exists()


def test_seeds_override_the_suite_and_the_estimate_comes_first(cold_and_warm, tmp_path):
    _, _, _, cache = cold_and_warm
    lines = []
    result = run(tiny(), tmp_path / "seeds", cache, seeds="1-2", announce=lines.append)
    assert result.summary["seeds"] == [1, 2]
    assert sorted(result.episodes["seed"].unique()) == [1, 2]
    assert (result.summary["cache"]["cached"], result.summary["cache"]["simulated"]) == (2, 2)
    # the estimate, then the phases after the episodes (issue 25: said on any output)
    assert lines[-3].startswith("suite tiny: 4 episodes (2 cached, 2 to simulate) on 1 "
                                "worker(s): about ")
    assert lines[-2].startswith("episodes done (") and lines[-2].endswith("scoring ...")
    assert lines[-1].startswith("scored (") and "writing the tables" in lines[-1]
    with pytest.raises(ParameterError, match="seeds"):
        run(tiny(), tmp_path / "bad", None, seeds="3-1")


def test_cli_cache_info_and_prune(cold_and_warm, tmp_path, capsys):
    root = tmp_path / "cli-cache"
    cache = EpisodeCache(root)
    entries = list(cold_and_warm[3].folder.glob("*/*.episode"))
    for path in entries:
        target = cache.folder / path.parent.name / path.name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(path.read_bytes())
    assert main(["bench", "cache", "info", "--cache", str(root)]) == 0
    assert f"{len(entries)} episode(s)" in capsys.readouterr().out
    assert main(["bench", "cache", "prune", "--cache", str(root), "--max-size", "0"]) == 0
    assert f"removed {len(entries)} entries" in capsys.readouterr().out
    assert main(["bench", "cache", "prune", "--cache", str(root), "--max-size", "x"]) == 2
    assert "--max-size must be" in capsys.readouterr().err


def test_cached_episodes_labelled_in_batches_equal_single_ones(tmp_path):
    """Seeds whose names sort otherwise as text (s10 < s8), one missing entry among the
    hits: the batch's tables still come out in the episodes' order, equal to a cold run
    (the run that filled the empty cache, which simulated every episode: such a run equals
    one without a cache, test_a_warm_run_reads_every_episode_and_equals_a_cold_run)."""
    suite = tiny(seeds="8-11")
    cache = EpisodeCache(tmp_path / "cache")
    cold = run(suite, tmp_path / "fill", cache)
    assert (cold.summary["cache"]["cached"], cold.summary["cache"]["simulated"]) == (0, 8)
    entries = sorted(cache.folder.glob("*/*.episode"))
    entries[3].unlink()
    warm = run(suite, tmp_path / "warm", without_runs(cache))
    assert (warm.summary["cache"]["cached"], warm.summary["cache"]["simulated"]) == (7, 1)
    assert_same_results(cold, warm)


def test_recall_reads_what_the_cache_holds_for_a_run_in_one_pass(tmp_path):
    cache = EpisodeCache(tmp_path)
    trajectories, episodes = rollout("merge", "lane-keeping", [0], duration=2, progress=False)
    trajectories = trajectories.reset_index(drop=True)
    row = episodes.iloc[0].to_dict()
    names = ("episodes", "labels")
    keys = [episode_key({"env": "merge"}, {"policy": "idm"}, seed, {}) for seed in range(3)]
    labels = [episode_key({"labels": seed}, {}, seed, {}) for seed in range(3)]
    for (key, doc), (label, label_doc) in zip(keys, labels, strict=True):
        cache.put(key, doc, trajectories, row, 1.0)
        cache.put_labels(label, label_doc, {"episodes": episodes,
                                            "labels": pd.DataFrame({"sdl": ["a"]})})
    cache.labels_path(labels[1][0]).write_bytes(b"damaged")
    cache.record_timings({"merge": 2.0}, {})
    recalled = cache.recall([(labels[0][0], keys[0][0], True),  # held whole
                             (labels[1][0], keys[1][0], False),  # its label entry damaged
                             (labels[2][0], keys[2][0], False),  # held without trajectories
                             (None, None, True)], names)  # not cached
    assert sorted(recalled.labelled) == [0, 2]
    tables, kept = recalled.labelled[0]
    assert set(tables) == set(names) and tables["labels"]["sdl"].tolist() == ["a"]
    pd.testing.assert_frame_equal(kept, trajectories)
    assert recalled.labelled[2][1] is None
    assert list(recalled.notes) == [1] and "refused and deleted" in recalled.notes[1]
    assert not cache.labels_path(labels[1][0]).exists()
    assert recalled.stored == [True, True, True, False]  # episode 1: its rollout is stored
    assert recalled.timings["simulated"] == {"merge": 2.0}
    # a label entry without every table asked for is no hit
    assert not cache.recall([(labels[0][0], keys[0][0], True)], (*names, "segments")).labelled
