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


def swerve(peak: float, speed: float, w_out: float, side: int, w_back: float = 0.02
           ) -> pd.DataFrame:
    """A car that swerves `peak` m sideways and comes back to its line: its yaw rate is
    +w_out until it is `peak` m out (heading up and back to 0), -w_out past 0, then +w_back
    (under w_str, 0.0283) straightens it; integrated at 1 kHz, sampled at 10 Hz. The turn
    pair ends on its way back, less than 1.5 m out; the straightening is sub-threshold."""
    fine = 1000
    d1 = np.sqrt(peak / speed / w_out)  # out: the heading rises and falls at w_out
    h2 = np.sqrt(2 * w_out * d1 * d1 / (1 / w_out + 1 / w_back))  # swung past: back to 0
    pieces = [(1.5, 0.0), (d1, w_out), (d1 + h2 / w_out, -w_out), (h2 / w_back, w_back),
              (3.0, 0.0)]
    w = side * np.concatenate([np.full(round(d * fine), r) for d, r in pieces])
    h = np.cumsum(w) / fine
    x, y = np.cumsum(speed * np.cos(h)) / fine, np.cumsum(speed * np.sin(h)) / fine
    k = np.arange(0, len(w), fine // 10)
    return pd.DataFrame({"scenario_id": "s", "track_id": "car", "t": k / fine, "x": x[k],
                         "y": y[k], "heading": h[k], "speed": speed})


@pytest.mark.parametrize("side", [1, -1], ids=["left", "right"])
@pytest.mark.parametrize("speed", [12.0, 20.0, 30.0])
@pytest.mark.parametrize("peak", [1.6, 1.8, 2.4])
@pytest.mark.parametrize("w_out", [0.06, 0.1, 0.15])
def test_a_swerve_past_a_merges_offset_that_comes_back_is_no_turn(side, speed, peak, w_out):
    # SPEC 4.3: the turns' heading comes back and they end less than merge_offset (1.5 m)
    # sideways from where they started: they moved less than a merge, however far out they
    # went (1.6-2.4 m here, past the 1.5 m at every step of the old wiggle rule, which left
    # 34 of these 54 as "Left Turn > Right Turn" or a lone turn). Some pairs end 1.5 m out
    # or more, parallel: a merge by SPEC 4.3's own test; none is a Turn.
    table = swerve(peak, speed, w_out, side)
    assert np.abs(table["y"]).max() >= 1.5 and abs(table["y"].iloc[-1]) < 0.05
    lateral = tb.label(table, level="maneuver")["lateral"].item()
    assert "Turn" not in lateral
    merge = "Left Merge" if side > 0 else "Right Merge"
    assert lateral in ("Straight", f"Straight > {merge} > Straight")


def lane_change(offset: float, seconds: float, speed: float, side: int, back: bool = False,
                pause: float = 2.0) -> pd.DataFrame:
    """A lane change of `offset` m over `seconds` at `speed` (a smooth S: y = offset (u -
    sin(2 pi u) / (2 pi))); with `back`, a second one back to the first lane after `pause`."""
    t = np.arange(0, 4 + 2 * seconds + pause + 3, 0.1)
    u1 = np.clip((t - 2) / seconds, 0, 1)
    y = offset * (u1 - np.sin(2 * np.pi * u1) / (2 * np.pi))
    if back:
        u2 = np.clip((t - 2 - seconds - pause) / seconds, 0, 1)
        y = y - offset * (u2 - np.sin(2 * np.pi * u2) / (2 * np.pi))
    y = side * y
    x = speed * t
    heading = np.arctan2(np.gradient(y, t), np.gradient(x, t))
    return pd.DataFrame({"scenario_id": "s", "track_id": "car", "t": t, "x": x, "y": y,
                         "heading": heading, "speed": speed})


@pytest.mark.parametrize("side", [1, -1], ids=["left", "right"])
@pytest.mark.parametrize("speed", [12.0, 20.0, 30.0])
@pytest.mark.parametrize("offset, seconds", [(3.5, 3.0), (4.0, 3.5), (3.0, 2.5), (2.5, 3.0)])
def test_completed_lane_changes_stay_merges_one_or_two_in_a_row(side, speed, offset, seconds):
    # the wiggle reads the sideways move where the turns end: a lane change ends a lane
    # width out, parallel (a merge), and one out and back again ends where it started but is
    # two merges (four turns, or three, which the chain splits), at every speed and side
    merge = "Left Merge" if side > 0 else "Right Merge"
    other = "Right Merge" if side > 0 else "Left Merge"
    one = tb.label(lane_change(offset, seconds, speed, side), level="maneuver")
    assert one["lateral"].item() == f"Straight > {merge} > Straight"
    two = tb.label(lane_change(offset, seconds, speed, side, back=True), level="maneuver")
    assert two["lateral"].item() == f"Straight > {merge} > Straight > {other} > Straight"


@pytest.mark.parametrize("side", [1, -1], ids=["left", "right"])
def test_a_completed_lane_change_stays_a_merge_and_two_in_a_row_two_merges(side):
    table = tb.behaviour("left_lane_change")
    if side < 0:
        table = table.assign(y=-table["y"], heading=-table["heading"])
    name = "Left Merge" if side > 0 else "Right Merge"
    assert tb.label(table, level="maneuver")["lateral"].item() == f"Straight > {name} > Straight"
    two = tb.label(tb.behaviour("two_lane_changes"), level="maneuver")["lateral"].item()
    assert two.count("Merge") == 2 and "Turn" not in two


def overshoot(speed: float, side: int, back: float, settle: float, turn: float = 0.0
              ) -> pd.DataFrame:
    """A lane change 4 m out over 2.5 s at `speed` that overshoots: it swings `back` m
    towards its old lane over 1.5 s, then out again to 4.14 m over `settle` s and settles
    at 4 m (cosine steps between those points; highway-env's IDM ego of seed 25). With
    `turn` [rad], the car then turns that far (towards `side`) over 4 s: a lane change
    before a bend."""
    t = np.arange(0, 16, 0.1)
    knots_t = [0.0, 2.0, 4.5, 6.0, 6.0 + settle, 16.0]
    knots_y = [0.0, 0.0, 4.0, 4.0 - back, 4.14, 4.0]
    y = np.zeros_like(t)
    for t0, t1, y0, y1 in zip(knots_t, knots_t[1:], knots_y, knots_y[1:], strict=False):
        u = np.clip((t - t0) / (t1 - t0), 0, 1)
        inside = (t >= t0) & (t <= t1)
        y[inside] = y0 + (y1 - y0) * (1 - np.cos(np.pi * u[inside])) / 2
    heading = np.arctan2(np.gradient(y, t), np.gradient(speed * t, t))
    bend = turn * np.clip((t - 6.0 - settle) / 4.0, 0, 1)
    heading = heading + bend
    step = np.r_[0.0, np.diff(t)]
    x = np.cumsum(speed * np.cos(bend) * step)
    y = y + np.cumsum(speed * np.sin(bend) * step)
    return pd.DataFrame({"scenario_id": "s", "track_id": "car", "t": t, "x": x,
                         "y": side * y, "heading": side * heading, "speed": speed})


@pytest.mark.parametrize("side", [1, -1], ids=["left", "right"])
@pytest.mark.parametrize("speed", [15.0, 20.0, 25.0, 30.0])
@pytest.mark.parametrize("back, settle", [(0.6, 2.5), (1.0, 3.5), (1.3, 2.5), (1.3, 3.5)])
def test_a_lane_change_that_overshoots_and_settles_is_a_merge(side, speed, back, settle):
    # the settling turn starts where the merge ends, its heading still off the lane's: it
    # is a wiggle measured from the heading where the merge started (18 of 48 such lane
    # changes were "Merge > Turn" when it was measured only from its own start)
    lateral = tb.label(overshoot(speed, side, back, settle), level="maneuver")["lateral"]
    assert "Turn" not in lateral.item()


@pytest.mark.parametrize("side", [1, -1], ids=["left", "right"])
@pytest.mark.parametrize("speed", [15.0, 25.0])
def test_a_lane_change_before_a_bend_keeps_the_bends_turn(side, speed):
    # the heading does not come back to the lane's direction: a turn, merge or not before
    table = overshoot(speed, side, 1.0, 3.5, turn=0.5)
    turn = "Left" if side > 0 else "Right"
    assert f"{turn} Turn" in tb.label(table, level="maneuver")["lateral"].item()


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
