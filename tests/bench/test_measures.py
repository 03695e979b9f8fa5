"""Ego safety and efficiency measures on hand-built scenes."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.measures import (
    BURN_IN_S,
    MEASURES,
    TTC_CAP_S,
    VEHICLE_LENGTH,
    ego_measures,
    ego_step_measures,
    ego_steps,
    register_measure,
)
from tap_bench.bench.suite import GateConfig, gate_metrics
from tap_bench.errors import RegistrationError, TrajectoryTableError


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
    # a leader 90 m ahead at 10 m/s, the ego at 20 m/s: its reach is 4 s x 20 m/s = 80 m, so
    # the leader counts from t = 1 s (centre 80 m ahead) on; at step k the bumper gap is then
    # 85 - k m, closing at 10 m/s; the car alongside is never a leader
    scene = pd.concat([track("s", "ego", 0, 0, 20, ego=True), track("s", "1", 90, 0, 10),
                       track("s", "2", 2, 4.0, 20)], ignore_index=True)
    steps = ego_step_measures(scene)
    assert len(steps) == 60 and (steps["scenario_id"] == "s").all()
    gap = (90 - 10 * steps["t"] - VEHICLE_LENGTH).where(steps["t"] >= 1.0 - 1e-9)
    assert np.allclose(steps["gap_m"], gap, equal_nan=True)
    assert steps["gap_m"].isna().sum() == 10
    assert np.allclose(steps["headway_s"], np.minimum(gap / 20, 10.0), equal_nan=True)
    assert np.allclose(steps["ttc_s"], np.minimum(gap / 10, TTC_CAP_S), equal_nan=True)
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


# -- along the path (SPEC 6 and 7): circles, curves, crashes ------------------------------

def arc_track(sid, tid, radius, s0, v, *, n=60, ego=False, crashed_at=None, radius_at=None):
    """A vehicle counter-clockwise on a circle of ``radius`` about the origin, starting at
    arc length ``s0`` (measured on the ego's circle of radius 50 m); ``radius_at(t)`` may
    change its radius (a lane change on the curve)."""
    t = np.arange(n) / 10
    r = np.full(n, float(radius)) if radius_at is None else radius_at(t)
    angle = (s0 + v * t) / 50.0
    x, y = r * np.cos(angle), r * np.sin(angle)
    heading = np.arctan2(np.gradient(y), np.gradient(x))
    speed = np.hypot(np.gradient(x), np.gradient(y)) * 10
    crashed = np.zeros(n, bool) if crashed_at is None else t >= crashed_at - 1e-9
    return pd.DataFrame({"scenario_id": sid, "track_id": tid, "t": t, "x": x, "y": y,
                         "heading": heading, "speed": speed, "is_ego": ego,
                         "crashed": crashed, "env": "h", "policy": "p", "seed": 0})


def test_leader_on_a_circle_is_found_and_the_inner_lane_is_not():
    # ego at 15 m/s on a 50 m circle; a slower car 40 m ahead on the arc; a car on the
    # inner lane (46 m) just ahead of the ego
    ego = arc_track("s", "ego", 50, 0, 15, ego=True)
    lead = arc_track("s", "1", 50, 40, 10)
    inner = arc_track("s", "2", 46, 8, 15)
    steps = ego_steps(pd.concat([ego, lead, inner], ignore_index=True))
    table = pd.concat([ego, lead, inner], ignore_index=True)
    leaders = set(table["track_id"].to_numpy()[steps.leader_row[steps.leader_row >= 0]])
    assert leaders == {"1"}
    # gap along the arc: 40 - 5 * t - one vehicle length; closing 5 m/s
    k = 30
    assert steps.gap[k] == pytest.approx(40 - 5 * steps.t[k] - VEHICLE_LENGTH, abs=0.2)
    assert steps.ttc[k] == pytest.approx(steps.gap[k] / 5, rel=0.02)
    # the old straight strip saw the leader leave it (40 m along a 50 m circle is 15 m off
    # the ego's heading), so this is the case the path frame exists for. With the leader
    # recorded for 4 s only (while it is on the ego's recorded path, not on the straight
    # extension beyond it), the smallest TTC is at 3.9 s.
    table = pd.concat([ego, arc_track("s", "1", 50, 40, 10, n=40), inner], ignore_index=True)
    m = ego_measures(table).iloc[0]
    assert m["min_ttc_s"] == pytest.approx((40 - 5 * 3.9 - VEHICLE_LENGTH) / 5, rel=0.01)


def test_a_crash_at_1_5_s_scores_zero_whatever_the_burn_in():
    # the ego runs into a stopped car: contact at 1.5 s, inside the 2 s burn-in
    ego = track("s", "ego", 0, 0, 10, ego=True, crashed_at=1.5, n=40)
    stopped = track("s", "1", 20, 0, 0, n=40)
    scene = pd.concat([ego, stopped], ignore_index=True)
    m = ego_measures(scene).iloc[0]
    assert BURN_IN_S > 1.5
    assert m["crashed"] and m["min_ttc_s"] == 0.0 and m["min_headway_s"] == 0.0
    steps = ego_steps(scene)
    # the conflict that led to the crash is scored from its start, burn-in or not
    assert np.isfinite(steps.ttc[0]) and steps.ttc[0] == pytest.approx(15 / 10)


def test_a_conflict_in_the_burn_in_that_does_not_crash_is_dropped():
    # the same approach, but the ego stops 1 m short at 1.2 s and the car drives away
    ego = track("s", "ego", 0, 0, 10, ego=True, n=40)
    ego.loc[ego["t"] >= 1.2, "speed"] = 0.0
    ego.loc[ego["t"] >= 1.2, "x"] = 12.0
    lead = track("s", "1", 18, 0, 0, n=40)
    lead.loc[lead["t"] >= 1.2, "speed"] = 15.0
    lead.loc[lead["t"] >= 1.2, "x"] = 18 + 15 * (lead["t"] - 1.2)
    m = ego_measures(pd.concat([ego, lead], ignore_index=True)).iloc[0]
    assert not m["crashed"] and m["min_ttc_s"] == TTC_CAP_S


def test_a_crash_with_no_leader_in_the_corridor_is_still_zero():
    # a side impact: nobody ahead in the corridor, but the ego is crashed from 3 s on
    ego = track("s", "ego", 0, 0, 10, ego=True, crashed_at=3.0)
    side = track("s", "1", 0, 4.0, 10)
    m = ego_measures(pd.concat([ego, side], ignore_index=True)).iloc[0]
    assert m["min_ttc_s"] == 0.0 and m["min_headway_s"] == 0.0


def test_cut_in_on_a_curve_becomes_the_leader_once_in_the_corridor():
    # on a 50 m circle the car 15 m ahead on the outer lane (54 m) moves into the ego's lane
    # between 2 and 4 s, 3 m/s slower than the ego
    def radius(t):
        return 54 - 4 * np.clip((t - 2.0) / 2.0, 0, 1)

    ego = arc_track("s", "ego", 50, 0, 15, ego=True)
    cutter = arc_track("s", "7", None, 30, 12, radius_at=radius, n=45)
    table = pd.concat([ego, cutter], ignore_index=True)
    steps = ego_steps(table)
    has = steps.leader_row >= 0
    first = int(np.flatnonzero(has)[0])
    # the corridor is 1.8 m: the cutter enters when its radius is below 51.8 m
    assert radius(steps.t[first]) <= 51.8 + 0.15
    assert radius(steps.t[first - 1]) > 51.8 - 0.15
    assert not has[:first].any() and has[first:45].all()
    # from then on the gap shrinks at 3 m/s: the smallest TTC is at the last step, 4.4 s
    m = ego_measures(table).iloc[0]
    assert m["min_ttc_s"] == pytest.approx((30 - 3 * 4.4 - VEHICLE_LENGTH) / 3, rel=0.03)


def test_length_column_sets_the_bumper_gap():
    scene = pd.concat([track("s", "ego", 0, 0, 20, ego=True), track("s", "1", 100, 0, 10)],
                      ignore_index=True)
    scene["length"] = np.where(scene["track_id"] == "ego", 4.0, 12.0)  # a truck ahead
    m = ego_measures(scene).iloc[0]
    assert m["min_ttc_s"] == pytest.approx(min((100 - 59 - 8) / 10, TTC_CAP_S))


# -- the registry ------------------------------------------------------------------------

def test_registry_refuses_duplicates_and_measures_without_margin():
    with pytest.raises(RegistrationError, match="already registered"):
        register_measure("min_ttc_s", unit="s", higher_is_better=True, margin=1.0,
                         description="again")(lambda steps: steps.minimum(steps.ttc))
    for bad in (None, -1.0, float("nan"), float("inf"), np.float64("nan"), -np.inf, True):
        with pytest.raises(RegistrationError, match="needs a gate margin"):
            register_measure("max_decel", unit="m/s^2", higher_is_better=True, margin=bad,
                             description="hardest braking")(lambda steps: steps.t)
    assert "max_decel" not in MEASURES


def test_a_measure_is_one_function_and_one_entry():
    @register_measure("max_decel", unit="m/s^2", higher_is_better=True, margin=0.5,
                      description="hardest braking of the ego")
    def max_decel(steps):
        return steps.minimum(steps.accel)

    try:
        ego = track("s", "ego", 0, 0, 20, ego=True, accel=-2.0, n=30)
        out = ego_measures(ego)
        assert out["max_decel"].iloc[0] == pytest.approx(-2.0)
        gate = GateConfig()
        assert gate.margins["max_decel"] == 0.5  # the gate checks it with its margin
        assert "max_decel" in gate_metrics()
        assert GateConfig(margins={"crashed": 0.2}).margins["max_decel"] == 0.5
    finally:
        MEASURES.unregister("max_decel")
    assert "max_decel" not in gate_metrics()


def test_no_crashed_roundabout_episode_keeps_a_capped_ttc():
    """The demo's defect on a short rollout: idm-aggressive crashes in the roundabout on
    seeds 2 and 5, which the straight-strip leader search scored with the capped TTC of
    10 s; each crashed episode must score TTC and headway 0."""
    from tap_bench.sim import rollout

    trajectories, _ = rollout("roundabout", "idm-aggressive", [0, 1, 2, 4, 5], progress=False)
    m = ego_measures(trajectories)
    crashed = m[m["crashed"].astype(bool)]
    assert len(crashed) >= 1, "no crash: the test would not test anything"
    assert (crashed["min_ttc_s"] == 0).all() and (crashed["min_headway_s"] == 0).all()
    assert (m.loc[~m["crashed"].astype(bool), "min_ttc_s"] > 0).all()


# -- issue 21: the leader beyond the record, "no leader", jerk ------------------------------

def _road(radius, side, ego_speed, others):
    from tap_bench.synthetic import road_scene
    return road_scene(radius, side, ego_speed=ego_speed, others=others)


@pytest.mark.parametrize("side", [1, -1], ids=["left", "right"])
@pytest.mark.parametrize("radius", [30.0, 60.0, 200.0])
def test_a_car_stopped_25_m_ahead_of_the_records_end_on_a_curve_as_on_a_straight(radius,
                                                                                   side):
    # the ego drives at 10 m/s for 9.1 s (91 m); a car stands 25 m beyond its last position
    # along the road: bumper gap 20 m at the last step, closing at 10 m/s: TTC 2.0 s and
    # headway 2.0 s, found on the same steps as on a straight road: those where it stands
    # within the ego's reach (60 m at 10 m/s) along the road
    n = 91
    v = np.full(n, 10.0)
    stop = {"lead": (90.0 + 25.0, np.zeros(n), 0.0)}
    straight = ego_steps(_road(np.inf, side, v, stop))
    curve_table = _road(radius, side, v, stop)
    curve = ego_steps(curve_table)
    m = ego_measures(curve_table).iloc[0]
    assert m["min_ttc_s"] == pytest.approx(2.0, abs=0.02)
    assert m["min_headway_s"] == pytest.approx(2.0, abs=0.02)
    assert ((curve.leader_row >= 0) == (straight.leader_row >= 0)).mean() >= 0.98
    along = 115.0 - 10.0 * curve.t  # centre to centre along the road
    assert (curve.leader_row[along <= 59.5] >= 0).all()
    assert (curve.leader_row[along > 60.5] < 0).all()


@pytest.mark.parametrize("radius", [60.0, np.inf])
def test_a_leader_braking_on_a_curve_inside_the_record_is_never_lost(radius):
    # 12.1 s; the leader starts 30 m ahead at 10 m/s and brakes at 2 m/s^2 from 3.5 s to a
    # stop 90 m on; the ego brakes at 2 m/s^2 from 3 s to a stop 55 m on: 35 m apart,
    # the leader beyond the end of the ego's record once both stand
    n = 121
    t = np.arange(n) / 10
    ego = np.clip(10 - 2 * np.clip(t - 3, 0, None), 0, None)
    lead = np.clip(10 - 2 * np.clip(t - 3.5, 0, None), 0, None)
    steps = ego_steps(_road(radius, 1, ego, {"lead": (30.0, lead, 0.0)}))
    assert (steps.leader_row >= 0).all()


def test_no_leader_is_not_a_10_s_observation():
    from tap_bench.bench.measures import leader_counts
    # a car in the next lane only: nobody ahead in the corridor after the burn-in
    scene = pd.concat([track("s", "ego", 0, 0, 20, ego=True), track("s", "1", 30, 4.0, 20),
                       track("t", "ego", 0, 0, 20, ego=True), track("t", "1", 30, 0.0, 20)],
                      ignore_index=True)
    m = ego_measures(scene).set_index("scenario_id")
    assert np.isnan(m.loc["s", "min_ttc_s"]) and np.isnan(m.loc["s", "min_headway_s"])
    # a leader never closed in on: TTC at its cap (an observation), headway 25 m / 20 m/s
    assert m.loc["t", "min_ttc_s"] == TTC_CAP_S
    assert m.loc["t", "min_headway_s"] == pytest.approx(25 / 20)
    counts = leader_counts(ego_steps(scene)).set_index("scenario_id")
    assert counts.loc["s", "no_leader"] and not counts.loc["t", "no_leader"]
    assert counts.loc["t", "leader_steps"] == 60 - round(BURN_IN_S * 10)


def test_jerk_of_a_hand_worked_speed_profile_and_of_noise():
    from tap_bench.bench.measures import JERK_WINDOW_STEPS
    # v = 10 + t^2 / 2: a = t, jerk 1 m/s^3 everywhere; quadratic Savitzky-Golay fits are
    # exact on it (and on a = t), away from the ends of the run
    n = 91
    t = np.arange(n) / 10
    ego = pd.DataFrame({"scenario_id": "s", "track_id": "ego", "t": t, "x": 10 * t + t ** 3 / 6,
                        "y": 0.0, "heading": 0.0, "speed": 10 + t ** 2 / 2, "is_ego": True})
    from tap_bench.bench.measures import smoothed_jerk
    jerk = smoothed_jerk(ego_steps(ego))
    assert jerk == pytest.approx(1.0, abs=1e-6)  # the end fits are exact on a quadratic too
    assert JERK_WINDOW_STEPS == 15
    # speed quantised to 0.05 m/s at a constant 15 m/s +- noise: second differences give
    # about 0.05 * sqrt(6) * 100 / 2 = 6 m/s^3; the filter leaves well under 0.5
    rng = np.random.default_rng(0)
    noisy = ego.assign(speed=15 + np.round(rng.normal(0, 0.03, n) / 0.05) * 0.05,
                       x=15 * t)
    assert ego_measures(noisy)["rms_jerk"].iloc[0] < 0.5
    # a run shorter than the window has no jerk
    short = ego.iloc[:10]
    assert np.isnan(ego_measures(short)["rms_jerk"].iloc[0])


def test_savgol_derivative_is_scipy_s_and_its_fit_is_computed_once():
    """The Savitzky-Golay slope equals scipy's savgol_filter(deriv=1, mode="interp") over
    windows, orders and lengths; its least-squares fit is made once per (window, order) and
    is read-only, so a caller cannot change the next call's result."""
    signal = pytest.importorskip("scipy.signal")
    from tap_bench.bench.measures import _savgol_fit, savgol_derivative

    rng = np.random.default_rng(2)
    for window, order, n in ((15, 2, 15), (15, 2, 91), (7, 3, 40), (5, 1, 6), (21, 4, 300)):
        y = np.cumsum(rng.normal(0, 1, n))
        ours = savgol_derivative(y, window, order, 0.1)
        assert ours == pytest.approx(signal.savgol_filter(y, window, order, deriv=1,
                                                          delta=0.1, mode="interp"),
                                     rel=1e-9, abs=1e-9)
        assert (savgol_derivative(y, window, order, 0.1) == ours).all()
    x, fit = _savgol_fit(15, 2)
    assert _savgol_fit(15, 2)[1] is fit and not fit.flags.writeable and not x.flags.writeable


@pytest.mark.parametrize("side", [1, -1], ids=["left", "right"])
@pytest.mark.parametrize("radius", [15.0, 20.0, 30.0])
def test_a_car_stopped_on_the_road_out_of_a_turn_whose_exit_the_record_cuts(radius, side):
    # a 90-degree turn: 2 s straight, a circle of `radius`, then the yaw rate falls to 0
    # over 3 s; the record ends half way through that fall and a car stands 25 m on along
    # the road (still in the exit). The line's curvature falls on as it fell: the car is the
    # leader at every step where it stands within the ego's reach (60 m at 10 m/s) along the
    # road, TTC and headway 2.0 s at the end (a straight road's figures)
    from tap_bench.synthetic import from_controls
    v, w0, fall = 10.0, side * 10.0 / radius, 3.0
    turn_s = (np.pi / 2 - abs(w0) * fall / 2) / abs(w0)
    t = np.arange(0, 2 + turn_s + fall + 6, 0.1)
    w = np.where(t < 2, 0, np.where(t < 2 + turn_s, w0, np.where(
        t < 2 + turn_s + fall, w0 * (1 - (t - 2 - turn_s) / fall), 0)))
    full = from_controls(np.full(len(t), v), w, track_id="ego")
    end = round((2 + turn_s + fall / 2) * 10)
    ego = full.iloc[:end + 1].assign(is_ego=True)
    car = full.iloc[[end + 25] * len(ego)].assign(
        t=ego["t"].to_numpy(), speed=0.0, track_id="car", is_ego=False)
    table = pd.concat([ego, car], ignore_index=True)
    steps = ego_steps(table)
    m = ego_measures(table).iloc[0]
    along = (end + 25 - np.arange(end + 1)) * v / 10  # centre to centre along the road
    assert (steps.leader_row[along <= 59.5] >= 0).all()
    assert (steps.leader_row[along > 60.5] < 0).all()
    assert m["min_ttc_s"] == pytest.approx(2.0, abs=0.05)
