"""Glitches of real tracks (SPEC section 2): hand-worked fixtures, paper thresholds.

Each fixture shows one glitch a real WOMD track has; the expected repair and label are
worked out beside it. Plausibility defaults: r_min 5 m, w_noise 0.5 rad/s, a_max 10 m/s^2
(a spike jumps by more than 1 m/s per step on both sides), v_heading 0.5 m/s, min_travel 1 m.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import tap_bench as tb
from tap_bench.errors import TapBenchError, TrajectoryTableError
from tap_bench.kinematics import Plausibility, compute_kinematics
from tap_bench.synthetic import from_controls
from tap_bench.trajectories import validate_and_index


def kinematics(table: pd.DataFrame):
    return compute_kinematics(validate_and_index(table))


def parked_with_pi_flip() -> pd.DataFrame:
    """A parked car as WOMD records it: positions jitter by 2 cm, the heading by 0.005 rad,
    the speed reads 0.2 to 0.6 m/s (above v_stop), and the box flips by pi for 2 s."""
    rng = np.random.default_rng(7)
    n = 91
    heading = 0.3 + rng.normal(0.0, 0.005, n)
    heading[40:60] += np.pi
    return pd.DataFrame({
        "scenario_id": "glitches", "track_id": "parked_flip", "t": np.arange(n) * 0.1,
        "x": 10.0 + rng.normal(0.0, 0.02, n), "y": 5.0 + rng.normal(0.0, 0.02, n),
        "heading": np.angle(np.exp(1j * heading)), "speed": rng.uniform(0.2, 0.6, n)})


def speed_spikes() -> pd.DataFrame:
    """A straight cruise at 10 m/s whose speed reads 30 m/s at step 45 and 25 m/s at steps
    70 and 71."""
    table = from_controls(np.full(91, 10.0), np.zeros(91), track_id="spikes")
    table.loc[45, "speed"] = 30.0
    table.loc[[70, 71], "speed"] = 25.0
    return table


def reversing_car() -> pd.DataFrame:
    """A car backing up at 3 m/s along a path that curves at 0.2 rad/s: it moves along
    heading0 = pi while its nose points the other way."""
    table = from_controls(np.full(91, 3.0), np.full(91, -0.2), heading0=np.pi,
                          track_id="reversing")
    table["heading"] = np.angle(np.exp(1j * (table["heading"] - np.pi)))
    return table


def right_turn_with_first_step_glitch() -> pd.DataFrame:
    """A right turn at -0.2 rad/s and 6 m/s whose first heading is 2.7 rad off (the box
    flipped at the first valid step, as in a3bb37c2 track 81)."""
    table = from_controls(np.full(60, 6.0), np.full(60, -0.2), track_id="first_glitch")
    table.loc[0, "heading"] = np.angle(np.exp(1j * (table.loc[0, "heading"] + 2.7)))
    return table


def creeping_in_place() -> pd.DataFrame:
    """A car that creeps 0.6 m (0.2 m/s for 3 s) while its heading turns by 0.6 rad, then
    stands: it never gets 1 m from its start, so it never turns."""
    speed = np.concatenate([np.full(30, 0.2), np.zeros(61)])
    return from_controls(speed, np.concatenate([np.full(30, 0.2), np.zeros(61)]),
                         track_id="creeping")


def test_parked_car_with_a_pi_flip_is_straight():
    table = parked_with_pi_flip()
    kin = kinematics(table)
    # The flip in and the flip back are the only heading changes above the bound
    # (0.6 m/s / 5 m + 0.5 rad/s = 0.62 rad/s; the 0.005 rad jitter changes by 0.1 rad/s).
    assert np.flatnonzero(kin.heading_glitch).tolist() == [40, 60]
    assert kin.travel[0] < 0.1 and not kin.trusted.any()
    assert np.all(kin.w == 0.0)
    labels = tb.label(table, level="all")
    assert set(labels["lateral"]) == {"Straight"}
    assert labels["heading_glitches"].tolist() == [2] * 4
    # heading repaired: the folded flips leave it within the jitter of 0.3 rad
    assert np.allclose(kin.heading, 0.3, atol=0.05)


def test_speed_spikes_are_replaced_and_counted():
    kin = kinematics(speed_spikes())
    assert np.flatnonzero(kin.speed_glitch).tolist() == [45, 70, 71]
    assert np.allclose(kin.v, 10.0) and np.allclose(kin.a, 0.0)
    labels = tb.label(speed_spikes(), level="all")
    assert labels["sdl"].tolist()[-1] == "Straight | Maintain Slow Speed"
    assert labels["speed_glitches"].tolist() == [3] * 4


def test_a_real_speed_change_is_not_a_spike():
    # braking at 8 m/s^2 (0.8 m/s per step) and an emergency stop at 9.5 m/s^2: no spike
    speed = np.concatenate([np.full(20, 20.0), 20.0 - 0.8 * np.arange(1, 21),
                            np.full(20, 4.0), np.maximum(4.0 - 0.95 * np.arange(1, 31), 0.0)])
    kin = kinematics(from_controls(speed, np.zeros(len(speed))))
    assert not kin.speed_glitch.any()
    assert np.allclose(kin.v, speed)


def test_reversing_car_is_labelled_reversing_and_its_path_turn():
    # SPEC 4.6: backing up for 1 s or more is Reversing, and the lateral label is the turn
    # of the path: it travels along a path curving right at 0.2 rad/s (its nose turns the
    # same way), so Right Turn, as driving forwards along the same path
    table = reversing_car()
    kin = kinematics(table)
    assert kin.reversing.all() and not kin.trusted.any()
    labels = tb.label(table, level="all").set_index("level")
    assert labels.loc["maneuver", "lateral"] == "Right Turn"
    assert labels.loc["maneuver", "longitudinal"] == "Reversing"
    assert labels.loc["action", "sdl"] == "Aggressive Right Turn | Reversing"
    assert labels["reversing_steps"].tolist() == [91] * 4
    steps = tb.tap(table).steps()
    assert steps["reversing"].all() and not steps["heading_trusted"].any()
    forwards = from_controls(np.full(91, 3.0), np.full(91, -0.2))
    assert tb.label(forwards, level="maneuver")["lateral"].item() == "Right Turn"


@pytest.mark.parametrize("steps_back, expected", [(5, "Maintain Speed"), (9, "Maintain Speed"),
                                                  (10, "Maintain Speed > Reversing"),
                                                  (30, "Maintain Speed > Reversing")])
def test_reversing_needs_1_s(steps_back, expected):
    # stage 2 on its own: 6 s at 2 m/s, the last `steps_back` steps moving backwards
    from tap_bench import sdl
    from tap_bench.stages import run_stages
    from tap_bench.thresholds import resolve_thresholds
    n = 60
    reversing = np.arange(n) >= n - steps_back
    labels = run_stages(np.zeros(n), np.zeros(n), np.full(n, 2.0), np.array([n]),
                        resolve_thresholds("paper"), heading=np.zeros(n),
                        x=np.arange(n) * 0.2, y=np.zeros(n), reversing=reversing)
    codes = labels.maneuver_longitudinal
    names = [sdl.LONGITUDINAL_NAMES[c] for c in codes[np.r_[True, codes[1:] != codes[:-1]]]]
    assert " > ".join(names) == expected


def test_heading_glitch_at_the_first_step_of_a_right_turn():
    table = right_turn_with_first_step_glitch()
    kin = kinematics(table)
    assert kin.heading_glitch.tolist().count(True) == 1 and kin.heading_glitch[1]
    # the one-sided first difference is bounded by 6/5 + 0.5 = 1.7 rad/s, then w = -0.2
    assert abs(kin.w[0]) <= 1.7 + 1e-9 and np.allclose(kin.w[2:], -0.2)
    assert np.allclose(np.diff(kin.heading[1:]), -0.02)
    labels = tb.label(table, level="all").set_index("level")["lateral"]
    # The trace still shows the bounded glitch: w = 1.7 at step 0 and (0.17 - 0.02) / 0.2
    # = 0.75 at step 1, a 2-step Left Turn; the low-pass removes it (its window means
    # (1.7 + 0.75 - 8 * 0.2) / 10 = 0.085 > w_str, still 2 steps: it joins the Right Turn).
    # |w| = 0.2 > w_med: Aggressive.
    assert labels["trace"] == "Left Turn > Right Turn"
    assert labels[["trend", "maneuver", "action"]].tolist() == [
        "Right Turn", "Right Turn", "Aggressive Right Turn"]


def test_a_car_that_moves_less_than_a_metre_never_turns():
    table = creeping_in_place()
    kin = kinematics(table)
    assert 0.4 < kin.travel[0] < 1.0
    labels = tb.label(table, level="all")
    assert set(labels["lateral"]) == {"Straight"}
    # the same creep at 2 m/s travels 6 m: a turn
    fast = from_controls(np.concatenate([np.full(30, 2.0), np.zeros(61)]),
                         np.concatenate([np.full(30, 0.2), np.zeros(61)]))
    assert "Left Turn" in tb.label(fast, level="maneuver")["lateral"].item()


def test_glitch_report_per_track():
    table = pd.concat([parked_with_pi_flip(), speed_spikes(), reversing_car(),
                       tb.behaviour("cruise_medium")], ignore_index=True)
    report = tb.tap(table).glitches().set_index("track_id")
    assert report.loc["parked_flip", ["heading_glitches", "speed_glitches"]].tolist() == [2, 0]
    assert bool(report.loc["parked_flip", "still"])
    assert report.loc["spikes", "speed_glitches"] == 3
    assert report.loc["reversing", "reversing_steps"] == 91
    assert report.loc["cruise_medium", ["heading_glitches", "speed_glitches",
                                        "reversing_steps"]].tolist() == [0, 0, 0]


def test_plausibility_parameters_are_checked_and_used():
    with pytest.raises(TapBenchError, match="r_min"):
        Plausibility(r_min=0.0)
    with pytest.raises(TapBenchError, match="min_travel"):
        Plausibility(min_travel=-1.0)
    # with min_travel 0.1 m the creeping car's turn is trusted again
    table = creeping_in_place()
    loose = tb.label(table, level="maneuver", plausibility=Plausibility(min_travel=0.1,
                                                                        v_heading=0.1))
    assert "Left Turn" in loose["lateral"].item()


@pytest.mark.parametrize(("column", "value", "match"), [
    ("speed", 1e30, "no vehicle moves faster than 100 m/s"),
    ("speed", 100.5, "no vehicle moves faster than 100 m/s"),
    ("x", 2e7, "beyond 1e\\+07 m"),
    ("y", -1.5e7, "beyond 1e\\+07 m"),
])
def test_values_no_vehicle_can_have_are_input_errors(column, value, match):
    table = tb.behaviour("cruise_slow")
    table.loc[17, column] = value
    with pytest.raises(TrajectoryTableError, match=match) as err:
        tb.label(table, source="trips.csv")
    assert err.value.column == column and err.value.row == 17
    assert "trips.csv" in str(err.value) and "row 17" in str(err.value)
    # an invalid row may hold anything
    table["valid"] = True
    table.loc[17, "valid"] = False
    tb.label(table)


def test_fit_refuses_an_impossible_speed(tmp_path, capsys):
    from tap_bench.cli import main

    table = tb.sample_table(n_random=20)
    table.loc[5, "speed"] = 1e30
    path = tmp_path / "bad.parquet"
    tb.write_table(table, path)
    assert main(["fit", str(path), "-o", str(tmp_path / "th.json")]) == 2
    err = capsys.readouterr().err
    assert "bad.parquet" in err and "speed is 1e+30 m/s at row 5" in err
    assert not (tmp_path / "th.json").exists()


def test_the_reviews_reversing_car_backs_8_8_m_turning_52_degrees():
    # the review's real case, rebuilt: 1 m/s backwards for 8.8 s along a path turning 52
    # degrees to the right; labelled Straight | Maintain Speed before SPEC 4.6
    n = 89
    table = from_controls(np.full(n, 1.0), np.full(n, -np.radians(52) / 8.8),
                          heading0=np.pi, track_id="backing")
    table["heading"] = np.angle(np.exp(1j * (table["heading"] - np.pi)))
    assert tb.label(table, level="maneuver")["sdl"].item() == "Right Turn | Reversing"
