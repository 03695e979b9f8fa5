"""The interaction axis (SPEC 7) on hand-worked scenes, on a straight road and on a circle.

Every scene is 8 s at 10 Hz; the ego (``"ego"``) drives at constant speed. Expected labels
are worked out from the definitions in tap_bench/interactions.py: e.g. a car that moves from
the next lane (4 m to the left) into the ego's lane with a half-cosine profile between 2 and
5 s crosses the corridor edge (1.8 m) at about 3.6 s: Free Driving until 2.6 s, Cut-in for
2 s (from 1 s before the crossing), then Following.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tap_bench.labelling import tap

T = np.round(np.arange(80) / 10, 10)
R = 60.0  # circle radius [m]


def lane_offset(t0: float, t1: float, start: float, end: float):
    """Lateral offset moving from ``start`` to ``end`` with a half-cosine between t0 and t1."""
    def f(t):
        u = np.clip((t - t0) / (t1 - t0), 0, 1)
        return start + (end - start) * (1 - np.cos(np.pi * u)) / 2
    return f


def vehicle(tid: str, s_of_t, off_of_t, *, circle: bool, ego: bool = False) -> pd.DataFrame:
    """A vehicle given its arc position s(t) [m] along the ego's lane and its offset to the
    left of that lane; on a straight road (x along the lane) or a counter-clockwise circle."""
    s, off = s_of_t(T), off_of_t(T)
    if circle:
        r = R - off  # left of a counter-clockwise lane is towards the centre
        x, y = r * np.cos(s / R), r * np.sin(s / R)
    else:
        x, y = s, off
    dx, dy = np.gradient(x, T), np.gradient(y, T)
    return pd.DataFrame({"scenario_id": "scene", "track_id": tid, "t": T, "x": x, "y": y,
                         "heading": np.arctan2(dy, dx), "speed": np.hypot(dx, dy),
                         "object_type": "vehicle", "is_ego": ego})


def const(v: float, s0: float = 0.0):
    return lambda t: s0 + v * t


def flat(value: float):
    return lambda t: np.full_like(t, value)


def label_scene(*tracks: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    result = tap(pd.concat(tracks, ignore_index=True), interactions="ego")
    labels = result.labels("maneuver")
    segs = result.segments("maneuver")
    ego_rows = labels["track_id"] == "ego"
    inter = segs[(segs["axis"] == "interaction") & (segs["track_id"] == "ego")]
    return labels[ego_rows].iloc[0], inter.reset_index(drop=True)


def runs(inter: pd.DataFrame) -> list[tuple[str, str | None]]:
    return [(r.label, None if pd.isna(r.other_track_id) else r.other_track_id)
            for r in inter.itertuples()]


@pytest.fixture(params=[False, True], ids=["straight", "circle"])
def circle(request) -> bool:
    return request.param


def test_following_at_constant_gap(circle):
    row, inter = label_scene(vehicle("ego", const(15), flat(0), circle=circle, ego=True),
                             vehicle("lead", const(15, 25), flat(0), circle=circle))
    assert row["interaction"] == "Following (lead)"
    assert runs(inter) == [("Following", "lead")]
    assert inter["t_start"].iloc[0] == 0 and inter["t_end"].iloc[0] == pytest.approx(8.0)


def test_nobody_ahead_is_free_driving(circle):
    # a car in the next lane ahead and one far ahead in the ego's lane (beyond 60 m)
    _, inter = label_scene(vehicle("ego", const(12), flat(0), circle=circle, ego=True),
                             vehicle("side", const(12, 10), flat(4), circle=circle),
                             vehicle("far", const(12, 70), flat(0), circle=circle))
    assert runs(inter) == [("Free Driving", None)]


def test_an_ego_alone_is_free_driving(circle):
    # no other track at all: no (ego step, other) pair to index (this raised IndexError)
    _, inter = label_scene(vehicle("ego", const(12), flat(0), circle=circle, ego=True))
    assert runs(inter) == [("Free Driving", None)]


def test_cut_in_20_m_ahead_names_the_agent(circle):
    cutter = vehicle("cutter", const(15, 20), lane_offset(2, 5, 4, 0), circle=circle)
    row, inter = label_scene(vehicle("ego", const(15), flat(0), circle=circle, ego=True),
                             cutter)
    assert runs(inter) == [("Free Driving", None), ("Cut-in", "cutter"),
                           ("Following", "cutter")]
    # the corridor edge is crossed where the offset 2 + 2 cos(pi u) is 1.8 m: u = 0.532;
    # the Cut-in starts 1 s before
    t_cross = 2 + 3 * np.arccos(-0.1) / np.pi
    assert inter["t_start"].iloc[1] == pytest.approx(t_cross - 1.0, abs=0.15)
    assert inter["t_end"].iloc[1] - inter["t_start"].iloc[1] == pytest.approx(2.0)
    assert row["interaction"] == "Free Driving > Cut-in (cutter) > Following (cutter)"


def test_cut_out_of_the_leader(circle):
    lead = vehicle("lead", const(15, 25), lane_offset(2, 5, 0, 4), circle=circle)
    _, inter = label_scene(vehicle("ego", const(15), flat(0), circle=circle, ego=True),
                             lead)
    assert runs(inter) == [("Following", "lead"), ("Cut-out", "lead"), ("Free Driving", None)]
    t_cross = 2 + 3 * np.arccos(0.1) / np.pi  # 2 - 2 cos(pi u) = 1.8: u = 0.468
    assert inter["t_start"].iloc[1] == pytest.approx(t_cross, abs=0.15)


def test_overtaking_a_slower_car_in_the_next_lane(circle):
    # 10 m/s faster, starting 30 m behind its front: alongside (s = 0) at 3 s
    _, inter = label_scene(vehicle("ego", const(25), flat(0), circle=circle, ego=True),
                             vehicle("slow", const(15, 30), flat(4), circle=circle))
    assert runs(inter) == [("Free Driving", None), ("Overtaking", "slow"),
                           ("Free Driving", None)]
    mid = (inter["t_start"].iloc[1] + inter["t_end"].iloc[1]) / 2
    assert mid == pytest.approx(3.0, abs=0.15)
    assert inter["t_end"].iloc[1] - inter["t_start"].iloc[1] >= 1.0


def test_being_overtaken(circle):
    _, inter = label_scene(vehicle("ego", const(15), flat(0), circle=circle, ego=True),
                             vehicle("fast", const(25, -30), flat(-4), circle=circle))
    assert runs(inter) == [("Free Driving", None), ("Being Overtaken", "fast"),
                           ("Free Driving", None)]


def test_lead_braking(circle):
    # the leader brakes at 3 m/s^2 from 3 s to 5 s (paper a_dec: -1.37 m/s^2)
    def s_lead(t):
        v = 15 - 3 * np.clip(t - 3, 0, 2)
        return 40 + np.concatenate([[0], np.cumsum((v[1:] + v[:-1]) / 2 * np.diff(t))])
    _, inter = label_scene(vehicle("ego", const(15), flat(0), circle=circle, ego=True),
                             vehicle("lead", s_lead, flat(0), circle=circle))
    assert runs(inter) == [("Following", "lead"), ("Lead Braking", "lead"),
                           ("Following", "lead")]
    assert inter["t_start"].iloc[1] == pytest.approx(3.0, abs=0.3)
    assert inter["t_end"].iloc[1] == pytest.approx(5.0, abs=0.3)


def test_the_ego_changing_lanes_behind_a_car_is_not_a_cut_in():
    # the ego moves into the left lane (2-5 s) behind a car 30 m ahead there: the car enters
    # the ego's corridor because the ego moved, so Following starts without a Cut-in
    row, inter = label_scene(vehicle("ego", const(20), lane_offset(2, 5, 0, 4), circle=False,
                                     ego=True),
                             vehicle("car", const(20, 30), flat(4), circle=False))
    assert "Merge" in row["lateral"]
    assert "Cut-in" not in row["interaction"]
    assert runs(inter)[-1] == ("Following", "car")


def test_label_table_columns_and_other_tracks():
    scene = pd.concat([vehicle("ego", const(15), flat(0), circle=False, ego=True),
                       vehicle("lead", const(15, 25), flat(0), circle=False)],
                      ignore_index=True)
    result = tap(scene, interactions="ego")
    labels = result.labels("all")
    assert "interaction" in labels.columns
    assert labels.loc[labels["track_id"] == "lead", "interaction"].isna().all()
    segs = result.segments("trend")
    lat = segs[segs["axis"] != "interaction"]
    assert lat["other_track_id"].isna().all()
    steps = result.steps()
    assert (steps.loc[steps["track_id"] == "ego", "interaction"] == "Following").all()
    every = tap(scene, interactions="all").labels("maneuver")
    assert every.set_index("track_id").loc["lead", "interaction"] == "Free Driving"
    with pytest.raises(Exception, match="is_ego"):
        tap(scene.drop(columns="is_ego"), interactions="ego")
    with pytest.raises(KeyError, match=r"(?i)did you mean"):
        tap(scene, interactions="egos")
    plain = tap(scene).labels("maneuver")
    assert "interaction" not in plain.columns


def test_cli_label_interactions(tmp_path, capsys):
    from tap_bench.cli import main

    scene = pd.concat([vehicle("ego", const(15), flat(0), circle=False, ego=True),
                       vehicle("cutter", const(15, 20), lane_offset(2, 5, 4, 0),
                               circle=False)], ignore_index=True)
    src, out, seg = tmp_path / "t.parquet", tmp_path / "l.parquet", tmp_path / "s.parquet"
    scene.to_parquet(src)
    assert main(["label", str(src), "-o", str(out), "--interactions", "--segments",
                 str(seg), "--level", "maneuver"]) == 0
    assert "Cut-in 1" in capsys.readouterr().out
    labels = pd.read_parquet(out).set_index("track_id")
    assert labels.loc["ego", "interaction"] == "Free Driving > Cut-in (cutter) > Following (cutter)"
    assert pd.isna(labels.loc["cutter", "interaction"])  # egos only when is_ego is given
    segs = pd.read_parquet(seg)
    cut = segs[(segs["axis"] == "interaction") & (segs["label"] == "Cut-in")]
    assert list(cut["other_track_id"]) == ["cutter"]
    assert main(["label", str(src), "-o", str(out), "--interactions", "all"]) == 0
    assert pd.read_parquet(out)["interaction"].notna().all()


# -- SPEC 7's guards (issue 21) --------------------------------------------------------------

def test_sequences_name_the_other_vehicle_when_the_leader_changes():
    # the first leader (12) turns off into the next lane at 3-5 s; 7, farther ahead in the
    # lane, then leads: "Following (12) > ... > Following (7)", never "Following > Following"
    row, _inter = label_scene(vehicle("ego", const(15), flat(0), circle=False, ego=True),
                             vehicle("12", const(15, 20), lane_offset(3, 5, 0, 4),
                                     circle=False),
                             vehicle("7", const(15, 45), flat(0), circle=False))
    seq = row["interaction"]
    assert seq.startswith("Following (12)") and seq.endswith("Following (7)")
    assert "Following > Following" not in seq


@pytest.mark.parametrize("side", [1, -1], ids=["left", "right"])
@pytest.mark.parametrize("radius", [30.0, 60.0, 200.0])
def test_a_car_keeping_pace_beside_on_a_curve_is_not_overtaken(radius, side):
    # in the next lane, level with the ego (its s wavers by +-1 m about 0): neither
    # Overtaking nor Being Overtaken, and the real leader 25 m ahead is followed throughout
    from tap_bench.synthetic import road_scene
    n = 80
    v = np.full(n, 12.0)
    waver = 12.0 + 1.0 * np.cos(np.arange(n) / 10 * 2.0)  # s = sin(2 t) / 2 about 0
    table = road_scene(radius, side, ego_speed=v,
                       others={"beside": (0.0, waver, 3.7 * side),
                               "lead": (25.0, v, 0.0)})
    result = tap(table, interactions="ego")
    labels = result.labels("maneuver").set_index("track_id")
    assert labels.loc["ego", "interaction"] == "Following (lead)"


def test_a_parked_ego_passed_by_a_car_in_the_next_lane_is_not_being_overtaken(circle):
    row, _inter = label_scene(vehicle("ego", const(0), flat(0), circle=circle, ego=True),
                             vehicle("passer", const(12, -40), flat(3.7), circle=circle))
    assert row["interaction"] == "Free Driving"


def test_a_parked_ego_behind_a_braking_car_follows_it():
    # the car ahead brakes; the ego stands: Following, not Lead Braking
    def braking(t):
        v = np.clip(8 - 4 * np.clip(t - 2, 0, None), 0, None)
        return 15 + np.cumsum(v) * 0.1
    row, _ = label_scene(vehicle("ego", const(0), flat(0), circle=False, ego=True),
                         vehicle("lead", braking, flat(0), circle=False))
    assert row["interaction"] == "Following (lead)"


def test_the_overtaking_guard_needs_a_vehicle_length_each_side(circle):
    # a slower car in the next lane goes from 20 m ahead to 20 m behind: Overtaking
    row, _ = label_scene(vehicle("ego", const(15), flat(0), circle=circle, ego=True),
                         vehicle("slow", const(10, 20), flat(3.7), circle=circle))
    assert "Overtaking (slow)" in row["interaction"]
    # one that only drifts from 3 m ahead to 3 m behind (less than a length each way): not
    row, _ = label_scene(vehicle("ego", const(15), flat(0), circle=circle, ego=True),
                         vehicle("level", const(14.25, 3), flat(3.7), circle=circle))
    assert "Overtak" not in row["interaction"]


def test_a_car_crossing_in_front_is_not_a_cut_in():
    # at an intersection a car crosses the ego's lane 20 m ahead, at right angles
    ego = vehicle("ego", const(10), flat(0), circle=False, ego=True)
    cross_t = T
    y = -20 + 8 * cross_t  # crosses y = 0 at 2.5 s
    crossing = pd.DataFrame({"scenario_id": "scene", "track_id": "crossing", "t": T,
                             "x": np.full(len(T), 45.0), "y": y,
                             "heading": np.full(len(T), np.pi / 2),
                             "speed": np.full(len(T), 8.0), "object_type": "vehicle",
                             "is_ego": False})
    row, _ = label_scene(ego, crossing)
    assert "Cut-in" not in row["interaction"]


def test_a_car_that_turns_into_the_lane_and_drives_on_is_a_cut_in():
    # the same car turning into the ego's lane 20 m ahead and driving along it: a Cut-in
    row, _ = label_scene(vehicle("ego", const(15), flat(0), circle=False, ego=True),
                         vehicle("cutter", const(15, 20), lane_offset(2, 5, 4, 0),
                                 circle=False))
    assert "Cut-in (cutter)" in row["interaction"]
