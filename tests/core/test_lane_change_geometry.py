"""SPEC 4.3 on generated paths: a lane change and its return on a straight road are merges,
never a Turn, whatever the road's direction; a real turn and a curved road keep their Turn.

Each path is a reference line (straight, or of constant curvature) and a sideways offset
from it, built on a 100 Hz grid and sampled at 10 Hz: positions and headings agree (the
heading is the path's own direction), as a vehicle's do. Paper thresholds.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
from hypothesis import assume, given, settings
from hypothesis import strategies as st

import tap_bench as tb
from tap_bench.synthetic import from_controls

W_STR = 0.0283  # the paper's straight bound [rad/s]
FINE = 100  # Hz of the construction grid
SETTINGS = settings(max_examples=60, deadline=None, derandomize=True)


def lane_step(t: np.ndarray, t0: float, seconds: float, width: float) -> np.ndarray:
    """A lane change of ``width`` m over ``seconds`` from ``t0``: width (u - sin(2 pi u) /
    (2 pi)), its heading zero at both ends and its yaw rate peaking at a quarter and three
    quarters of the way."""
    u = np.clip((t - t0) / seconds, 0, 1)
    return width * (u - np.sin(2 * np.pi * u) / (2 * np.pi))


def along(seconds: float, speed: float, offset, *, curvature: float = 0.0,
          heading0: float = 0.0, side: int = 1, keep: tuple[float, float] | None = None
          ) -> pd.DataFrame:
    """A car at ``speed`` along a line of ``curvature`` [1/m] (towards ``side``: +1 left),
    ``offset(t)`` m to the ``side`` of it, turned to start at ``heading0`` [rad]; 10 Hz
    rows over ``seconds`` (``keep``: only the rows of that time span)."""
    t = np.arange(0, seconds + 1e-9, 1 / FINE)
    s = speed * t
    k = side * curvature
    phi = k * s
    cx, cy = (s, np.zeros_like(s)) if k == 0 else (np.sin(phi) / k, (1 - np.cos(phi)) / k)
    d = side * offset(t)
    x, y = cx - d * np.sin(phi), cy + d * np.cos(phi)
    vx, vy = np.gradient(x, t), np.gradient(y, t)
    heading = np.unwrap(np.arctan2(vy, vx)) + heading0
    c, s0 = np.cos(heading0), np.sin(heading0)
    pick = np.arange(0, len(t), FINE // 10)
    if keep is not None:
        pick = pick[(t[pick] >= keep[0] - 1e-9) & (t[pick] <= keep[1] + 1e-9)]
    return pd.DataFrame({"scenario_id": "s", "track_id": "car",
                         "t": np.round(t[pick] - t[pick][0], 6),
                         "x": (c * x - s0 * y)[pick] + 120.0, "y": (s0 * x + c * y)[pick] - 40.0,
                         "heading": np.angle(np.exp(1j * heading[pick])),
                         "speed": np.hypot(vx, vy)[pick]})


def lateral(table: pd.DataFrame) -> str:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return tb.label(table, "paper", level="maneuver")["lateral"].item()


def names(side: int) -> tuple[str, str]:
    return ("Left", "Right") if side > 0 else ("Right", "Left")


lane_changes = st.fixed_dictionaries({
    "heading0": st.floats(0, 2 * np.pi), "side": st.sampled_from([1, -1]),
    "width": st.floats(3.0, 4.0), "speed": st.floats(5.0, 35.0),
    "seconds": st.floats(2.0, 8.0)})


def visible(p: dict) -> bool:
    """The lane change's peak yaw rate (2 pi width / (seconds^2 speed)) is twice w_str or
    more: its turns read as turns for long enough. A slower one is Straight to TAP, which
    reads lateral motion from the heading (no Turn either)."""
    return 2 * np.pi * p["width"] / (p["seconds"] ** 2 * p["speed"]) >= 2 * W_STR


def within_pi_6(p: dict) -> bool:
    """The heading stays within 25 degrees of the road's: SPEC 4.3 calls a lateral move
    that turns beyond pi/6 (Waymo's bound of a straight trajectory) an S-curve, two turns
    (5 m/s over 2 s makes 38 degrees: a swerve, not a lane change)."""
    return np.degrees(np.arctan(2 * p["width"] / (p["seconds"] * p["speed"]))) <= 25


def halves_last(p: dict) -> bool:
    """Each half of the lane change turns beyond w_str for 1 s or more (what the trend
    stage keeps: a shorter run is joined to its neighbour; docs/tap.md names the limit)."""
    peak = 2 * np.pi * p["width"] / (p["seconds"] ** 2 * p["speed"])
    # the yaw rate is peak sin(2 pi u): above w_str while sin > w_str / peak
    above = p["seconds"] * (0.5 - np.arcsin(min(1.0, W_STR / peak)) / np.pi)
    return above >= 1.05


@SETTINGS
@given(lane_changes, st.floats(0.0, 3.0))
def test_a_lane_change_and_its_return_on_a_straight_road_are_merges(p, pause):
    assume(within_pi_6(p) and halves_last(p))
    first, other = names(p["side"])
    t0, secs, width = 2.0, p["seconds"], p["width"]
    one = lateral(along(t0 + secs + 4, p["speed"], lambda t: lane_step(t, t0, secs, width),
                        heading0=p["heading0"], side=p["side"]))
    assert "Turn" not in one and f"{other} Merge" not in one
    assert f"{first} Merge" in one or not visible(p)

    def out_and_back(t):
        return lane_step(t, t0, secs, width) - lane_step(t, t0 + secs + pause, secs, width)

    two = lateral(along(t0 + 2 * secs + pause + 4, p["speed"], out_and_back,
                        heading0=p["heading0"], side=p["side"]))
    assert "Turn" not in two
    if visible(p):
        assert f"{first} Merge" in two and f"{other} Merge" in two


@SETTINGS
@given(lane_changes, st.floats(0.03, 0.1), st.floats(1.0, 2.0))
def test_a_lane_change_that_overshoots_and_settles_is_a_merge(p, over, settle):
    # out `over` times the width past the lane's centre and back, over `settle` times
    # the lane change's own duration (an overshoot gentler than the lane change)
    assume(within_pi_6(p) and halves_last(p))
    t0, secs, width = 2.0, p["seconds"], p["width"]
    swing = settle * secs

    def offset(t):
        u = np.clip((t - t0 - secs) / swing, 0, 1)
        return lane_step(t, t0, secs, width) + over * width * (1 - np.cos(2 * np.pi * u)) / 2

    got = lateral(along(t0 + secs + swing + 4, p["speed"], offset, heading0=p["heading0"],
                        side=p["side"]))
    _, other = names(p["side"])
    assert "Turn" not in got and f"{other} Merge" not in got


@SETTINGS
@given(st.floats(0, 2 * np.pi), st.sampled_from([1, -1]), st.floats(10.0, 200.0),
       st.floats(30.0, 180.0), st.floats(0.0, 1.0))
def test_a_real_turn_keeps_its_turn(heading0, side, radius, degrees, where):
    # straight, an arc of `radius` through `degrees`, straight; at a speed whose yaw rate
    # (speed / radius) is twice w_str or more and whose sideways acceleration is at most
    # 4 m/s^2
    low, high = max(3.0, 2.2 * W_STR * radius), min(35.0, np.sqrt(4 * radius))
    speed = low + where * (high - low)
    arc = np.radians(degrees) * radius / speed
    n = round((4 + arc) * 10) + 1
    t = np.arange(n) * 0.1
    yaw = np.where((t >= 2) & (t < 2 + arc), side * speed / radius, 0.0)
    got = lateral(from_controls(np.full(n, speed), yaw, heading0=heading0))
    turn, _ = names(side)
    assert f"{turn} Turn" in got and "Merge" not in got


@SETTINGS
@given(lane_changes, st.floats(100.0, 500.0), st.floats(0.0, 1.0), st.sampled_from([1, -1]))
def test_a_curved_road_keeps_its_turn_with_a_lane_change_on_it(p, radius, where, towards):
    # a road of constant curvature whose yaw rate is twice w_str or more: a Turn of its
    # side, with a lane change either way on it
    low, high = max(5.0, 2.2 * W_STR * radius), min(35.0, np.sqrt(3 * radius))
    speed = low + where * (high - low)
    t0, secs, width = 2.0, p["seconds"], p["width"]
    table = along(t0 + secs + 4, speed, lambda t: towards * lane_step(t, t0, secs, width),
                  curvature=1 / radius, heading0=p["heading0"], side=p["side"])
    turn, _ = names(p["side"])
    assert f"{turn} Turn" in lateral(table)
    plain = along(t0 + secs + 4, speed, lambda t: 0 * t, curvature=1 / radius,
                  heading0=p["heading0"], side=p["side"])
    assert lateral(plain) == f"{turn} Turn"


def controls(pieces: list[tuple[float, float]], speed: float) -> pd.DataFrame:
    """A track of constant ``speed`` whose yaw rate is ``rate`` [rad/s] for ``seconds``, per
    (seconds, rate) piece."""
    yaw = np.concatenate([np.full(round(s * 10), r) for s, r in pieces])
    return from_controls(np.full(len(yaw), speed), yaw)


def test_a_lane_change_and_its_return_at_once_are_two_merges_when_little_is_left():
    # out left (+0.1 rad/s for 1.5 s, -0.1 for 1.5 s: heading back at 0, 4.5 m left at
    # 20 m/s), then at once the way back (-0.1 for 0.9 s more, +0.06 for 1.5 s): the
    # middle Right run is back at heading 0 with 0.9 s of it left, under the 1 s a split
    # needed (IDM-aggressive seeds 0 and 44 on the highway); its rest and the last Left
    # run are the lateral move back, 2.2 m to the right, heading back at 0. Before:
    # "Straight > Left Merge > Straight", the way back lost
    table = controls([(2.0, 0.0), (1.5, 0.1), (1.5, -0.1), (0.9, -0.1), (1.5, 0.06),
                      (3.0, 0.0)], 20.0)
    assert lateral(table) == "Straight > Left Merge > Right Merge > Straight"


def test_a_lane_change_the_data_cuts_off_after_its_heading_peaked_is_a_merge():
    # +0.12 rad/s for 1.4 s (heading 0.168 rad, within merge_heading), then the yaw back
    # under w_str and turning back (-0.01 rad/s) for 0.4 s when the data ends (the trace
    # Straight at its second and third last steps): 3.2 m to the left at 20 m/s (IDM-
    # aggressive seed 43 on the highway, cut 1.4 s into a lane change). Still
    # turning when the data ends, or turned beyond 0.2 rad, it stays a turn (as in
    # tests/core/test_behaviours.py)
    assert lateral(controls([(2.0, 0.0), (1.4, 0.12), (0.4, -0.01)], 20.0)) == (
        "Straight > Left Merge")
    assert lateral(controls([(2.0, 0.0), (1.4, 0.12), (0.4, 0.01)], 20.0)) == (
        "Straight > Left Turn")
    assert lateral(controls([(2.0, 0.0), (1.9, 0.12), (0.4, -0.01)], 20.0)) == (
        "Straight > Left Turn")
