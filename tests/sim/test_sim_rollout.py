"""Rollouts: deterministic per seed in any worker count, shared initial traffic, failures
reported and the rest kept."""

from __future__ import annotations

import os

import pandas as pd
import pytest

import tap_bench
from tap_bench.cli import main
from tap_bench.execution import LocalBackend
from tap_bench.sim.policies import LaneKeepingPolicy
from tap_bench.sim.rollout import EPISODE_COLUMNS, EpisodeFailedWarning, rollout
from tap_bench.tableio import read_table


class FailsOnSeed(LaneKeepingPolicy):
    """Lane keeping that raises in the episode of one seed."""

    def __init__(self, seed: int, name: str = "fails-on-seed") -> None:
        super().__init__(name)
        self.bad_seed = seed
        self.seed = -1

    def reset(self, env, *, seed):
        super().reset(env, seed=seed)
        self.seed = seed

    def act(self, observation):
        if self.seed == self.bad_seed:
            raise ValueError(f"scripted failure on seed {self.seed}")
        return super().act(observation)


class KillsWorkerOnSeed(FailsOnSeed):
    """Lane keeping whose process dies in the episode of one seed."""

    def act(self, observation):
        if self.seed == self.bad_seed:
            os._exit(3)
        return LaneKeepingPolicy.act(self, observation)


_TWO_WORKERS = LocalBackend(2)
"""The two worker processes of this module's rollouts with two workers, started by the
first and kept until the module ends (``two_workers_kept``), where each rollout started its
own (about 1 CPU s a worker): ``rollout(..., workers=2)`` runs on a :class:`LocalBackend`
of 2 as this one; a worker that dies is replaced by a new one, as in a rollout of its own."""


@pytest.fixture(scope="module", autouse=True)
def two_workers_kept():
    with _TWO_WORKERS.kept():
        yield


def test_the_episode_table():
    trajectories, episodes = rollout("highway", "idm", "0-1", duration=3, progress=False)
    assert tuple(episodes.columns) == EPISODE_COLUMNS
    assert episodes["seed"].tolist() == [0, 1]
    assert (episodes["length"] == 3).all() and (episodes["duration_s"] == 3.0).all()
    assert episodes["truncated"].all() and not episodes["crashed"].any()
    ego = trajectories[trajectories["is_ego"] & (trajectories["seed"] == 1)]
    assert episodes["mean_speed"].iloc[1] == pytest.approx(ego["speed"].mean())


def test_same_seeds_same_tables_with_one_or_two_workers():
    one = rollout("merge", "random", [4, 1, 2], duration=3, progress=False)
    two = rollout("merge", "random", [4, 1, 2], duration=3, backend=_TWO_WORKERS,
                  progress=False)
    pd.testing.assert_frame_equal(one.trajectories, two.trajectories)
    pd.testing.assert_frame_equal(one.episodes, two.episodes)
    assert one.episodes["seed"].tolist() == [4, 1, 2]


def test_every_policy_meets_the_same_initial_traffic_on_a_seed():
    first = {}
    for policy in ("idm", "random", "lane-keeping"):
        table, _ = rollout("highway", policy, [5], duration=2, progress=False)
        start = table[table["t"] == 0.0].set_index("track_id")
        first[policy] = start[["x", "y", "heading", "speed"]].sort_index()
    pd.testing.assert_frame_equal(first["idm"], first["random"])
    pd.testing.assert_frame_equal(first["idm"], first["lane-keeping"])


def test_a_failing_episode_is_reported_and_the_rest_kept():
    with pytest.warns(EpisodeFailedWarning, match="seed 1: ValueError: scripted failure"):
        trajectories, episodes = rollout("merge", FailsOnSeed(1), [0, 1, 2], duration=2,
                                         progress=False)
    assert episodes["status"].tolist() == ["ok", "error", "ok"]
    assert "scripted failure on seed 1" in episodes["error"].iloc[1]
    assert set(trajectories["seed"]) == {0, 2}
    tap_bench.validate_trajectories(trajectories)


def test_a_dying_worker_loses_only_its_episode():
    with pytest.warns(EpisodeFailedWarning, match="worker process died"):
        trajectories, episodes = rollout("merge", KillsWorkerOnSeed(2), [0, 1, 2, 3],
                                         duration=2, backend=_TWO_WORKERS, progress=False)
    assert episodes["status"].tolist() == ["ok", "ok", "error", "ok"]
    assert set(trajectories["seed"]) == {0, 1, 3}


def test_the_cli_writes_both_tables(tmp_path, capsys):
    out = tmp_path / "idm.parquet"
    code = main(["rollout", "--env", "roundabout", "--policy", "idm", "--seeds", "0-1",
                 "--duration", "2", "-o", str(out), "--no-progress"])
    assert code == 0
    table = read_table(out)
    episodes = read_table(tmp_path / "idm.episodes.parquet")
    assert set(table["seed"]) == {0, 1} and episodes["status"].tolist() == ["ok", "ok"]
    assert "2/2 episodes" in capsys.readouterr().out


def test_bad_arguments_are_refused_before_any_work():
    with pytest.raises(ValueError, match="workers"):
        rollout("merge", "idm", [0], workers=0)
    with pytest.raises(ValueError, match="twice"):
        rollout("merge", "idm", [0, 0])
    with pytest.raises(tap_bench.UnknownNameError, match="Did you mean 'merge'"):
        rollout("merg", "idm", [0])
