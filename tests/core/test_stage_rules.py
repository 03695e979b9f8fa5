"""SPEC 4.3 (wiggles), 4.5 (a run agrees with its own average), 4.6 (reversing) and 4.7
(faster input resampled on entry), on hand-worked cases and generated variants.

Paper thresholds throughout: w_str 0.0283 rad/s, a_acc 1.5557 m/s^2, a_dec -1.3715 m/s^2.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

import tap_bench as tb
from tap_bench import sdl
from tap_bench.errors import ResampledWarning, TrajectoryTableError
from tap_bench.stages import run_stages
from tap_bench.thresholds import resolve_thresholds

TH = resolve_thresholds("paper")


def sequence(codes: np.ndarray, names: tuple[str, ...]) -> str:
    change = np.r_[True, codes[1:] != codes[:-1]]
    return " > ".join(names[c] for c in codes[change])


def stages(w, a, v):
    n = len(w)
    heading = np.cumsum(w) * 0.1
    return run_stages(np.asarray(w, float), np.asarray(a, float), np.asarray(v, float),
                      np.array([n]), TH, heading=heading, x=np.arange(n) * 1.0,
                      y=np.zeros(n))


# -- SPEC 4.5 --------------------------------------------------------------------------------

def test_a_turn_run_joined_over_a_spike_that_cancels_it_is_straight():
    # yaw 0.04 rad/s for 1 s, a -0.3 rad/s spike of 0.3 s, 0.04 again for 1 s. Stage 2: the
    # spike's window mean (3 x -0.3 + 7 x 0.04) / 10 = -0.062 makes it a Right run of 3
    # steps, the shortest, which joins its longer neighbour: one Left run of 23 steps whose
    # mean yaw rate is (20 x 0.04 - 0.9) / 23 = -0.004: it never turned left. Straight.
    w = np.r_[np.full(10, 0.04), np.full(3, -0.3), np.full(10, 0.04)]
    labels = stages(w, np.zeros(23), np.full(23, 10.0))
    assert sequence(labels.trend_lateral, sdl.LATERAL_NAMES) == "Straight"
    # without the spike, a run of 0.04 rad/s is a Left Turn (its mean agrees)
    labels = stages(np.full(23, 0.04), np.zeros(23), np.full(23, 10.0))
    assert sequence(labels.trend_lateral, sdl.LATERAL_NAMES) == "Left Turn"


def test_an_accelerate_run_whose_speed_change_is_small_maintains_speed():
    # a = 1.6 for 1 s, -3 for 0.3 s, 1.6 for 1 s: one Accelerate run after stage 2 whose
    # mean (32 - 9) / 23 = 1.0 m/s^2 is below a_acc: Maintain Speed
    a = np.r_[np.full(10, 1.6), np.full(3, -3.0), np.full(10, 1.6)]
    labels = stages(np.zeros(23), a, np.full(23, 10.0))
    assert sequence(labels.trend_longitudinal, sdl.LONGITUDINAL_NAMES) == "Maintain Speed"
    # and a Decelerate run: -1.5 with a +3 spike: mean (-30 + 9) / 23 = -0.9 > a_dec
    a = np.r_[np.full(10, -1.5), np.full(3, 3.0), np.full(10, -1.5)]
    labels = stages(np.zeros(23), a, np.full(23, 10.0))
    assert sequence(labels.trend_longitudinal, sdl.LONGITUDINAL_NAMES) == "Maintain Speed"


@pytest.mark.parametrize("seed", range(6))
def test_every_turn_and_speed_run_agrees_with_its_own_average(seed):
    # generated noisy trajectories: after stage 2 no turn run has a mean yaw rate on the
    # straight side of w_str, and no accelerate (decelerate) run a mean acceleration that
    # is not above a_acc (at or below a_dec)
    table = tb.random_trajectories(40, seed=seed)
    result = tb.tap(table, "paper")
    kin, rows = result.kinematics, result.step_rows
    w = np.where(kin.v[rows] <= TH.v_stop, 0.0, kin.w[rows])
    a = kin.a[rows]
    for codes, signal, checks in (
            (result.step_labels.trend_lateral, w,
             {sdl.LEFT: lambda m: m > TH.w_str, sdl.RIGHT: lambda m: m < -TH.w_str}),
            (result.step_labels.trend_longitudinal, a,
             {sdl.ACCELERATE: lambda m: m > TH.a_acc, sdl.DECELERATE: lambda m: m <= TH.a_dec})):
        seg = result.step_segment
        change = np.r_[True, (codes[1:] != codes[:-1]) | (seg[1:] != seg[:-1])]
        starts = np.flatnonzero(change)
        means = np.add.reduceat(signal, starts) / np.diff(np.r_[starts, len(codes)])
        for code, ok in checks.items():
            mine = codes[starts] == code
            assert ok(means[mine]).all()


# -- SPEC 4.3: wiggles -----------------------------------------------------------------------

def bump(amplitude: float, seconds: float, speed: float = 25.0, tail: float = 3.0):
    """A car on a straight road that moves `amplitude` m sideways and back (a cosine bump
    over `seconds`) at `speed`: an aborted lane change (y up, heading from positions)."""
    t = np.arange(0, 2 + seconds + tail, 0.1)
    u = np.clip((t - 2) / seconds, 0, 1)
    x = speed * t
    y = amplitude * (1 - np.cos(2 * np.pi * u)) / 2
    heading = np.arctan2(np.gradient(y, t), np.gradient(x, t))
    return pd.DataFrame({"scenario_id": "s", "track_id": "car", "t": t, "x": x, "y": y,
                         "heading": heading, "speed": np.hypot(np.gradient(x, t),
                                                               np.gradient(y, t))})


@pytest.mark.parametrize("side", [1, -1], ids=["left", "right"])
@pytest.mark.parametrize("amplitude, seconds", [(0.5, 3.0), (1.0, 4.0), (1.4, 4.0),
                                                (1.0, 6.0), (1.4, 3.0)])
def test_an_aborted_lane_change_is_a_wiggle_not_turns(amplitude, seconds, side):
    # out by under 1.5 m and back, heading under 5 degrees: no Turn, no Merge
    table = bump(side * amplitude, seconds)
    peak = np.degrees(np.abs(table["heading"]).max())
    assert peak < 5
    lateral = tb.label(table, level="maneuver")["lateral"].item()
    assert lateral == "Straight"


@pytest.mark.parametrize("side", [1, -1], ids=["left", "right"])
def test_a_completed_lane_change_stays_a_merge_and_two_in_a_row_two_merges(side):
    table = tb.behaviour("left_lane_change")
    if side < 0:
        table = table.assign(y=-table["y"], heading=-table["heading"])
    name = "Left Merge" if side > 0 else "Right Merge"
    assert tb.label(table, level="maneuver")["lateral"].item() == f"Straight > {name} > Straight"
    two = tb.label(tb.behaviour("two_lane_changes"), level="maneuver")["lateral"].item()
    assert two.count("Merge") == 2 and "Turn" not in two


# -- SPEC 4.7: faster input --------------------------------------------------------------------

def same_motion(rate: float, seconds: float = 9.0, seed: int = 0) -> pd.DataFrame:
    """A turn then a lane change, braking in between, sampled at `rate` Hz (exact
    positions of one continuous motion)."""
    fine = 1000
    t = np.arange(0, seconds + 1e-9, 1 / fine)
    yaw = np.where((t > 1) & (t < 3.5), 0.25, 0.0) + np.where(
        (t > 5) & (t < 6.5), 0.1, 0.0) - np.where((t > 6.5) & (t < 8), 0.1, 0.0)
    speed = 12 - 2 * np.clip(t - 3.5, 0, 1.5)
    heading = np.cumsum(yaw) / fine
    x = np.cumsum(speed * np.cos(heading)) / fine
    y = np.cumsum(speed * np.sin(heading)) / fine
    k = np.round(np.arange(0, seconds + 1e-9, 1 / rate) * fine).astype(int)
    return pd.DataFrame({"scenario_id": "s", "track_id": "car", "t": t[k], "x": x[k],
                         "y": y[k], "heading": heading[k], "speed": speed[k]})


@pytest.mark.parametrize("rate", [20.0, 25.0, 50.0])
def test_faster_input_is_resampled_on_entry_and_said(rate):
    reference = tb.label(same_motion(10.0), level="all")
    with pytest.warns(ResampledWarning, match=f"sampled at {rate:.3g} Hz; resampled to 10 Hz"):
        labels = tb.label(same_motion(rate), level="all")
    assert labels["sdl"].tolist() == reference["sdl"].tolist()


def test_slower_input_is_refused_with_the_fix():
    with pytest.raises(TrajectoryTableError, match="slower than 10 Hz is refused"):
        tb.label(same_motion(5.0))


def test_resampled_scenes_share_one_grid():
    # two tracks starting at 0.04 s and 0.13 s at 25 Hz: both on the multiples of 0.1 s
    a = same_motion(25.0).assign(t=lambda f: f["t"] + 0.04)
    b = same_motion(25.0).assign(track_id="other", t=lambda f: f["t"] + 0.12)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ResampledWarning)
        result = tb.tap(pd.concat([a, b], ignore_index=True))
    t = result.kinematics.t
    assert np.allclose(t * 10, np.round(t * 10))
