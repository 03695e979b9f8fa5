"""Ego safety and efficiency measures on hand-built scenes."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.measures import (
    BURN_IN_S,
    TTC_CAP_S,
    VEHICLE_LENGTH,
    ego_measures,
    ego_step_measures,
)
from tap_bench.errors import TrajectoryTableError


def track(sid, tid, x0, y, v, *, n=60, ego=False, crashed_at=None, accel=0.0):
    t = np.arange(n) / 10
    speed = v + accel * t
    x = x0 + v * t + 0.5 * accel * t * t
    crashed = np.zeros(n, bool) if crashed_at is None else t >= crashed_at
    return pd.DataFrame({"scenario_id": sid, "track_id": tid, "t": t, "x": x, "y": y,
                         "heading": 0.0, "speed": speed, "is_ego": ego, "crashed": crashed,
                         "env": "h", "policy": "p", "seed": 0})


def test_following_a_slower_leader_by_hand():
    # ego at 20 m/s; leader 100 m ahead at 10 m/s in the same lane; a car alongside (y 4 m)
    scene = pd.concat([track("s", "ego", 0, 0, 20, ego=True), track("s", "1", 100, 0, 10),
                       track("s", "2", 2, 4.0, 20)], ignore_index=True)
    m = ego_measures(scene).iloc[0]
    # closing at 10 m/s; the smallest gap is at the last step, t = 5.9 s:
    gap = 100 - 10 * 5.9 - VEHICLE_LENGTH  # 36 m: TTC 3.6 s, headway 1.8 s
    assert m["min_ttc_s"] == pytest.approx(min(gap / 10, TTC_CAP_S))
    assert m["min_headway_s"] == pytest.approx(min(gap / 20, 10.0))
    assert m["mean_speed"] == pytest.approx(20.0)
    assert m["rms_jerk"] == pytest.approx(0.0, abs=1e-6)
    assert not m["crashed"]
    assert m["duration_s"] == pytest.approx(6.0)


def test_step_measures_follow_the_closing_gap_by_hand():
    # a leader 90 m ahead (inside the 100 m look-ahead) at 10 m/s: at step k the bumper gap
    # is 85 - k m, closing at 10 m/s, the ego at 20 m/s; the car alongside is never a leader
    scene = pd.concat([track("s", "ego", 0, 0, 20, ego=True), track("s", "1", 90, 0, 10),
                       track("s", "2", 2, 4.0, 20)], ignore_index=True)
    steps = ego_step_measures(scene)
    assert len(steps) == 60 and (steps["scenario_id"] == "s").all()
    gap = 90 - 10 * steps["t"] - VEHICLE_LENGTH
    assert np.allclose(steps["gap_m"], gap)
    assert np.allclose(steps["headway_s"], np.minimum(gap / 20, 10.0))
    assert np.allclose(steps["ttc_s"], np.minimum(gap / 10, TTC_CAP_S))
    assert list(steps["scored"]) == [t >= BURN_IN_S - 1e-9 for t in steps["t"]]
    # the episode minimum is the minimum over the scored steps
    assert ego_measures(scene)["min_ttc_s"].iloc[0] == pytest.approx(
        steps.loc[steps["scored"], "ttc_s"].min())


def test_initial_gap_is_not_the_policys():
    # a leader that pulls away: the only close moment is the first second
    scene = pd.concat([track("s", "ego", 0, 0, 20, ego=True), track("s", "1", 8, 0, 30)],
                      ignore_index=True)
    m = ego_measures(scene).iloc[0]
    gap_after_burn_in = 8 + 10 * BURN_IN_S - VEHICLE_LENGTH
    assert m["min_headway_s"] == pytest.approx(gap_after_burn_in / 20)
    assert m["min_ttc_s"] == TTC_CAP_S  # never closing in


def test_alone_on_the_road_has_no_headway():
    m = ego_measures(track("s", "ego", 0, 0, 20, ego=True)).iloc[0]
    assert np.isnan(m["min_headway_s"]) and np.isnan(m["min_ttc_s"])


def test_crash_and_constant_jerk():
    ego = track("s", "ego", 0, 0, 10, ego=True, crashed_at=3.0, accel=1.0)
    m = ego_measures(ego).iloc[0]
    assert m["crashed"]
    assert m["rms_jerk"] == pytest.approx(0.0, abs=1e-6)  # constant acceleration


def test_one_row_per_scenario_and_ids_kept():
    scene = pd.concat([track("s1", "ego", 0, 0, 20, ego=True),
                       track("s2", "ego", 0, 0, 15, ego=True).assign(seed=1)],
                      ignore_index=True)
    out = ego_measures(scene)
    assert list(out["scenario_id"]) == ["s1", "s2"]
    assert list(out["seed"]) == [0, 1] and list(out["policy"]) == ["p", "p"]


def test_two_egos_and_missing_is_ego_are_errors():
    scene = pd.concat([track("s", "a", 0, 0, 20, ego=True), track("s", "b", 9, 0, 20,
                                                                  ego=True)])
    with pytest.raises(TrajectoryTableError, match="2 ego tracks"):
        ego_measures(scene)
    with pytest.raises(TrajectoryTableError, match="is_ego"):
        ego_measures(track("s", "a", 0, 0, 20).drop(columns="is_ego"))
