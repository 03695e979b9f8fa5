"""The episode table: one row per (env, policy, seed), from label, trajectory and rollout
episode tables."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.episodes import EPISODE_COLUMNS, ego_labels, episode_table
from tap_bench.errors import LabelTableError
from tap_bench.labelling import tap


def ego_track(sid: str, seed: int, n: int, v: float = 15.0) -> pd.DataFrame:
    t = np.arange(n) / 10
    return pd.DataFrame({"scenario_id": sid, "track_id": "ego", "t": t, "x": v * t, "y": 0.0,
                         "heading": 0.0, "speed": v, "is_ego": True, "env": "h",
                         "policy": "p", "seed": seed})


def test_an_ego_too_short_to_label_keeps_its_row():
    traj = pd.concat([ego_track("h/p/s0", 0, 60), ego_track("h/p/s1", 1, 5)],
                     ignore_index=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        labels = tap(traj, "paper").labels("all")
    eps = episode_table(labels=labels, trajectories=traj, level="maneuver")
    assert list(eps.columns[: len(EPISODE_COLUMNS)]) == list(EPISODE_COLUMNS)
    assert eps[["env", "policy", "seed"]].values.tolist() == [["h", "p", 0], ["h", "p", 1]]
    assert eps.loc[0, "sdl"] == "Straight | Maintain Speed"
    assert pd.isna(eps.loc[1, "sdl"])
    assert eps["mean_speed"].tolist() == pytest.approx([15.0, 15.0])


def test_rollout_episode_table_adds_failures_and_returns():
    traj = ego_track("h/p/s0", 0, 30)
    episodes = pd.DataFrame({"env": ["h", "h"], "policy": "p", "seed": [0, 1],
                             "return": [3.0, np.nan], "crashed": [False, False],
                             "mean_speed": [15.0, np.nan], "status": ["ok", "error"],
                             "error": ["", "ValueError: x"]})
    eps = episode_table(trajectories=traj, episodes=episodes, level="maneuver")
    assert eps["status"].tolist() == ["ok", "error"]
    assert eps.loc[0, "return"] == 3.0 and eps.loc[1, "error"] == "ValueError: x"


def test_longest_segment_is_the_egos_label():
    labels = pd.DataFrame({"scenario_id": ["s", "s"], "track_id": ["ego", "ego"],
                           "level": "maneuver", "lateral": ["Straight", "Left Turn"],
                           "longitudinal": ["Stopped", "Accelerate"],
                           "sdl": ["Straight | Stopped", "Left Turn | Accelerate"],
                           "t_start": [0.0, 3.0], "t_end": [2.0, 9.0], "is_ego": True,
                           "seed": 0, "policy": "p"})
    assert ego_labels(labels, "maneuver")["sdl"].tolist() == ["Left Turn | Accelerate"]


def test_missing_columns_and_levels_name_the_fix():
    labels = pd.DataFrame({"scenario_id": ["s"], "track_id": ["1"], "sdl": ["x | y"],
                           "lateral": ["x"], "longitudinal": ["y"], "level": "action"})
    with pytest.raises(LabelTableError, match="--level maneuver"):
        ego_labels(labels, "maneuver", source="f.parquet")
    with pytest.raises(LabelTableError, match="seed"):
        episode_table(labels=labels.assign(level="maneuver"), level="maneuver", policy="p")
    two = pd.concat([labels, labels.assign(track_id="2")]).assign(level="maneuver")
    with pytest.raises(LabelTableError, match="is_ego"):
        ego_labels(two, "maneuver")


def test_duration_is_one_column_when_both_tables_carry_it():
    # the measures and the rollout's episode table both have duration_s: one column, the
    # trajectories' value, and the rollout's for an episode without trajectory (issue 11)
    traj = ego_track("h/p/s0", 0, 30)
    episodes = pd.DataFrame({"env": ["h", "h"], "policy": "p", "seed": [0, 1],
                             "duration_s": [3.0, 1.5], "crashed": [False, False],
                             "mean_speed": [15.0, np.nan], "status": ["ok", "error"],
                             "error": ["", "ValueError: x"]})
    eps = episode_table(trajectories=traj, episodes=episodes, level="maneuver")
    assert not {"duration_s_x", "duration_s_y"} & set(eps.columns)
    assert eps["duration_s"].tolist() == pytest.approx([3.0, 1.5])


def test_one_outcome_cells_names_cells_whose_seeds_all_give_one_episode():
    from tap_bench.bench.scores.verdict import one_outcome_cells

    from .conftest import make_episodes

    rows = []
    for seed in range(4):
        same = {"sdl": "Straight | Cruise", "crashed": False, "mean_speed": 24.0,
                "min_ttc_s": 10.0}
        rows.append({"env": "exit", "policy": "idm", "seed": seed, **same})
        rows.append({"env": "exit", "policy": "random", "seed": seed, **same,
                     "mean_speed": 20.0 + seed})  # a measure varies: independent enough
        rows.append({"env": "highway", "policy": "idm", "seed": seed, **same,
                     "sdl": "Straight | Cruise" if seed else "Left Lane Change | Cruise"})
    table = make_episodes(rows)
    table.loc[(table["env"] == "highway") & (table["seed"] == 3), "status"] = "error"
    out = one_outcome_cells(table)
    assert out.to_dict("records") == [{"env": "exit", "policy": "idm", "n": 4}]
    assert one_outcome_cells(table[table["seed"] == 0]).empty  # one episode: not a sample
