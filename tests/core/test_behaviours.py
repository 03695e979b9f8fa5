"""Hand-worked behaviour fixtures: expected SDL labels at all four levels (paper thresholds).

Thresholds (paper): w 0.0283 / 0.0754 / 0.1541 rad/s, a -1.3715 / 1.5557 m/s^2,
v 0.1 / 10.214 / 24.4046 m/s. Fixtures are built by ``tap_bench.synthetic`` from per-step
controls: heading[k+1] - heading[k] = yaw[k] * 0.1 s, so the central-difference yaw rate at
a step is the mean of the commanded yaw of that step and the one before: a turn of yaw w
starting at step s reads w/2 at step s and at the step after it ends. The working for each
expectation is in the comment beside it.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import tap_bench as tb
from tap_bench.synthetic import from_controls

LEVELS = ("trace", "trend", "maneuver", "action")


def labels_of(table: pd.DataFrame) -> dict[str, str]:
    out = tb.label(table, "paper", level="all")
    assert len(out) == 4, "one segment expected"
    return dict(zip(out["level"], out["sdl"], strict=True))


EXPECTED = {
    # v = 5 m/s (<= 10.214 Slow), w = 0, a = 0.
    "cruise_slow": ("Straight | Maintain Speed",) * 3 + ("Straight | Maintain Slow Speed",),
    # 10.214 < 15 <= 24.4046: Medium.
    "cruise_medium": ("Straight | Maintain Speed",) * 3 + ("Straight | Maintain Medium Speed",),
    # 28 > 24.4046: Fast.
    "cruise_fast": ("Straight | Maintain Speed",) * 3 + ("Straight | Maintain Fast Speed",),
    # v = 0 < v_stop: trace knows nothing of speed (a = 0 Maintain); from trend on, Stopped.
    "parked": ("Straight | Maintain Speed",) + ("Straight | Stopped",) * 3,
    # yaw 0.05 for 3 s: the edge steps read 0.025 <= w_str, so the run is exactly the 30
    # turning steps; |w| = 0.05 in (0.0283, 0.0754]: Gradual. 8 m/s is Slow.
    "gradual_left_turn": ("Straight > Left Turn > Straight | Maintain Speed",) * 3
    + ("Straight > Gradual Left Turn > Straight | Maintain Slow Speed",),
    # yaw 0.12: the run has 31 steps, the two edge steps at 0.06 (Gradual) form 1-step
    # pieces, so the whole run takes the class of its mean |w| = 0.116: Medium.
    "medium_left_turn": ("Straight > Left Turn > Straight | Maintain Speed",) * 3
    + ("Straight > Medium Left Turn > Straight | Maintain Slow Speed",),
    # yaw 0.3: mean |w| = 0.29 > 0.1541: Aggressive.
    "aggressive_left_turn": ("Straight > Left Turn > Straight | Maintain Speed",) * 3
    + ("Straight > Aggressive Left Turn > Straight | Maintain Slow Speed",),
    "gradual_right_turn": ("Straight > Right Turn > Straight | Maintain Speed",) * 3
    + ("Straight > Gradual Right Turn > Straight | Maintain Slow Speed",),
    "medium_right_turn": ("Straight > Right Turn > Straight | Maintain Speed",) * 3
    + ("Straight > Medium Right Turn > Straight | Maintain Slow Speed",),
    "aggressive_right_turn": ("Straight > Right Turn > Straight | Maintain Speed",) * 3
    + ("Straight > Aggressive Right Turn > Straight | Maintain Slow Speed",),
    # +0.12 for 1.5 s then -0.12 for 1.5 s: the step between reads (0.12 - 0.12)/2 = 0, a
    # one-step Straight run. Trend: its 1 s window mean is ~0 (still Straight, still short),
    # so it joins its longer neighbour; both are 15 steps, the earlier (Left) wins. Maneuver:
    # Left then Right with no gap: Left Merge. 15 m/s: Medium.
    "left_lane_change": (
        "Straight > Left Turn > Straight > Right Turn > Straight | Maintain Speed",
        "Straight > Left Turn > Right Turn > Straight | Maintain Speed",
        "Straight > Left Merge > Straight | Maintain Speed",
        "Straight > Left Merge > Straight | Maintain Medium Speed",
    ),
    "right_lane_change": (
        "Straight > Right Turn > Straight > Left Turn > Straight | Maintain Speed",
        "Straight > Right Turn > Left Turn > Straight | Maintain Speed",
        "Straight > Right Merge > Straight | Maintain Speed",
        "Straight > Right Merge > Straight | Maintain Medium Speed",
    ),
    # A 2 s straight pause (< 4 s) between the turns: the pause survives the trend stage
    # (>= 1 s) and is swallowed by the merge.
    "left_lane_change_with_pause": (
        "Straight > Left Turn > Straight > Right Turn > Straight | Maintain Speed",
        "Straight > Left Turn > Straight > Right Turn > Straight | Maintain Speed",
        "Straight > Left Merge > Straight | Maintain Speed",
        "Straight > Left Merge > Straight | Maintain Medium Speed",
    ),
    # 4.5 s of straight commanded; the right turn's leading edge step reads -0.05, so the
    # straight run is 44 steps = 4.4 s > 4 s: two turns, no merge. Both turns are Medium.
    "two_turns_apart": (
        ("Straight > Left Turn > Straight > Right Turn > Straight | Maintain Speed",) * 3
        + ("Straight > Medium Left Turn > Straight > Medium Right Turn > Straight | "
           "Maintain Slow Speed",)
    ),
    # 1 s at 8 m/s, -2.5 m/s^2 for 3.2 s, 2.5 s stopped, +2 m/s^2 for 2.4 s. The first
    # braking step reads (7.75 - 8)/0.2 = -1.25 (Maintain), so the first run is 1.1 s.
    # Stopped from the first zero speed to the start of the pull-away. All speeds <= 8: Slow.
    "stop_and_go": (
        "Straight | Maintain Speed > Decelerate > Maintain Speed > Accelerate",
        "Straight | Maintain Speed > Decelerate > Stopped > Accelerate",
        "Straight | Maintain Speed > Decelerate > Stopped > Accelerate",
        "Straight | Maintain Slow Speed > Decelerate Slow Speed > Stopped > "
        "Accelerate Slow Speed",
    ),
    # 5 m/s + 3 m/s^2: Slow for 18 steps (v <= 10.214), Medium for 47, Fast for 14: every
    # piece >= 1 s, so the run is split. The last 12 steps are Maintain (v constant; the
    # step at the corner reads 1.5 <= 1.5557).
    "accelerate_through_bands": (
        ("Straight | Accelerate > Maintain Speed",) * 3
        + ("Straight | Accelerate Slow Speed > Accelerate Medium Speed > "
           "Accelerate Fast Speed > Maintain Fast Speed",)
    ),
    # Braking from 26 m/s at -4 m/s^2: only 4 steps of the Decelerate run are above
    # 24.4046 (Fast), a piece < 1 s, so the whole run takes its mean speed (22.2): Medium.
    "hard_brake": (
        ("Straight | Maintain Speed > Decelerate > Maintain Speed",) * 3
        + ("Straight | Maintain Fast Speed > Decelerate Medium Speed > "
           "Maintain Medium Speed",)
    ),
    # A 0.4 s blip of 0.05 rad/s reads 0.025, 0.05 x3, 0.025: a 3-step Left Turn in the
    # trace; its 1 s window mean is 0.02 <= w_str, so the low-pass makes it Straight.
    "flicker": ("Straight > Left Turn > Straight | Maintain Speed",)
    + ("Straight | Maintain Speed",) * 2 + ("Straight | Maintain Medium Speed",),
    # Yaw 0.5 for 6.3 s; the edge steps read 0.25 > w_str, so one Left run of 64 steps,
    # every |w| > 0.1541: Aggressive. A single turn, nothing to pair. 4 m/s: Slow.
    "u_turn": ("Straight > Left Turn > Straight | Maintain Speed",) * 3
    + ("Straight > Aggressive Left Turn > Straight | Maintain Slow Speed",),
    # 0.5 rad/s for 4 s then -0.1 for 1.2 s: the corner reads (0.5 - 0.1)/2 = 0.2 (Left),
    # the trailing edge -0.05 (Right): Left 41 steps, Right 13. They are adjacent, but the
    # net heading change is 2.0 - 0.12 = 1.88 rad > 0.2: no merge. Right run: 12 steps of
    # 0.1 (Medium) and one of 0.05 (Gradual, a piece < 1 s), so the run takes its mean
    # |w| = 0.096: Medium.
    "turn_exit_overshoot": ("Straight > Left Turn > Right Turn > Straight | Maintain Speed",)
    * 3 + ("Straight > Aggressive Left Turn > Medium Right Turn > Straight | "
           "Maintain Slow Speed",),
    # +0.4 for 2 s then -0.4 for 2 s: the corner step reads 0, a 1-step Straight run; its
    # window (4 steps of 0.4, the 0, 5 of -0.4) means -0.04 < -w_str: Right Turn. Maneuver:
    # the heading comes back and the car moves 5 m sideways, but it turned 0.8 rad away
    # from its start heading, farther than pi/6: two turns, both Aggressive (0.4).
    "s_curve": ("Straight > Left Turn > Straight > Right Turn > Straight | Maintain Speed",
                "Straight > Left Turn > Right Turn > Straight | Maintain Speed",
                "Straight > Left Turn > Right Turn > Straight | Maintain Speed",
                "Straight > Aggressive Left Turn > Aggressive Right Turn > Straight | "
                "Maintain Slow Speed"),
    # -0.12 for 1.5 s, +0.12 for 3 s, -0.12 for 1.5 s at 15 m/s. Each corner reads 0, a
    # 1-step Straight whose window means +-0.012 (Straight, still short): it joins its
    # longer neighbour, the 30-step Left run. Trend: Right, Left, Right. Maneuver: the
    # heading is back at its start half-way through the Left run (1.5 s left of it), so it
    # is split there: Right then Left, each back to the start heading, 0.18 rad at most
    # from it and about 4 m sideways: two merges.
    "two_lane_changes": (
        "Straight > Right Turn > Straight > Left Turn > Straight > Right Turn > Straight | "
        "Maintain Speed",
        "Straight > Right Turn > Left Turn > Right Turn > Straight | Maintain Speed",
        "Straight > Right Merge > Left Merge > Straight | Maintain Speed",
        "Straight > Right Merge > Left Merge > Straight | Maintain Medium Speed",
    ),
}


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_behaviour_labels_at_every_level(name):
    got = labels_of(tb.behaviour(name))
    assert tuple(got[level] for level in LEVELS) == EXPECTED[name]


def test_every_builtin_behaviour_has_hand_worked_labels():
    assert set(EXPECTED) == set(tb.synthetic.BEHAVIOURS)


def test_merge_gap_parameter_decides_a_merge():
    table = tb.behaviour("left_lane_change_with_pause")
    strict = tb.label(table, level="maneuver", config=tb.StageConfig(merge_gap=1.5))
    assert strict["lateral"].item() == "Straight > Left Turn > Straight > Right Turn > Straight"


def test_merges_pair_greedily_from_the_start():
    # L, R, L, R all close together: (L, R) and (L, R) pair into two Left Merges joined.
    yaw = np.concatenate([np.zeros(15), np.full(15, 0.12), np.full(15, -0.12), np.zeros(15),
                          np.full(15, 0.12), np.full(15, -0.12), np.zeros(15)])
    got = tb.label(from_controls(np.full(len(yaw), 15.0), yaw), level="maneuver")
    assert got["lateral"].item() == "Straight > Left Merge > Straight > Left Merge > Straight"
    # L, R, L: the first pair merges, the last Left stays a turn.
    yaw = np.concatenate([np.zeros(15), np.full(15, 0.12), np.full(15, -0.12), np.zeros(15),
                          np.full(15, 0.12), np.zeros(15)])
    got = tb.label(from_controls(np.full(len(yaw), 15.0), yaw), level="maneuver")
    assert got["lateral"].item() == "Straight > Left Merge > Straight > Left Turn > Straight"


def test_turn_split_into_intensities_when_every_piece_lasts():
    # 2 s at 0.05 (Gradual; its first step reads 0.025, Straight) then 2 s at 0.35: the
    # corner reads 0.2 and the trailing edge 0.175, both Aggressive. Pieces of 19 and 21
    # steps, both >= 1 s: kept apart.
    yaw = np.concatenate([np.zeros(20), np.full(20, 0.05), np.full(20, 0.35), np.zeros(20)])
    got = tb.label(from_controls(np.full(len(yaw), 8.0), yaw), level="action")
    assert got["lateral"].item() == ("Straight > Gradual Left Turn > Aggressive Left Turn > "
                                     "Straight")


def test_stopped_vehicle_yaw_noise_is_straight():
    rng = np.random.default_rng(0)
    yaw = rng.normal(0.0, 0.2, 91)  # a parked car whose heading jitters
    got = tb.label(from_controls(np.zeros(91), yaw), level="all")
    assert set(got["sdl"][got["level"] != "trace"]) == {"Straight | Stopped"}


def test_segment_table_tiles_each_trajectory():
    result = tb.tap(tb.behaviour("stop_and_go"))
    seg = result.segments("action")
    for _axis, part in seg.groupby("axis"):
        assert part["t_start"].iloc[0] == 0.0
        assert np.allclose(part["t_end"].iloc[-1], 9.1)
        assert np.allclose(part["t_start"].to_numpy()[1:], part["t_end"].to_numpy()[:-1])
    lon = seg[seg["axis"] == "longitudinal"]
    assert lon["label"].tolist() == ["Maintain Slow Speed", "Decelerate Slow Speed", "Stopped",
                                     "Accelerate Slow Speed"]
    assert np.allclose(lon["t_start"], [0.0, 1.1, 4.2, 6.8])


def test_step_table_has_every_level():
    result = tb.tap(tb.behaviour("left_lane_change"))
    steps = result.steps()
    assert len(steps) == 91
    assert steps["maneuver_lateral"].iloc[30] == "Left Merge"
    assert steps["trace_lateral"].iloc[35] == "Straight"
    assert steps["trend_lateral"].iloc[35] == "Left Turn"
    assert steps["action_longitudinal"].iloc[0] == "Maintain Medium Speed"


def test_merge_rule_parameters_decide_a_merge():
    # left_lane_change: the heading peaks at 0.18 rad and comes back; the car moves about
    # 15 m/s * 3 s * 0.09 = 4 m to the left over the pair
    table = tb.behaviour("left_lane_change")

    def lateral(**kw):
        return tb.label(table, level="maneuver", config=tb.StageConfig(**kw))["lateral"].item()

    assert lateral() == "Straight > Left Merge > Straight"
    assert lateral(merge_offset=3.5) == "Straight > Left Merge > Straight"
    # a pair that comes back but moves sideways less than merge_offset is a wiggle (an
    # aborted lane change), not two turns
    assert lateral(merge_offset=4.5) == "Straight"
    assert lateral(merge_excursion=0.15) == "Straight > Left Turn > Right Turn > Straight"
    # the S-curve turns 0.8 rad away: allowed that far, it is a lateral move
    s_curve = tb.label(tb.behaviour("s_curve"), level="maneuver",
                       config=tb.StageConfig(merge_excursion=1.0))
    assert s_curve["lateral"].item() == "Straight > Left Merge > Straight"
    # the turn-exit overshoot never comes back to its heading, whatever the excursion
    overshoot = tb.label(tb.behaviour("turn_exit_overshoot"), level="maneuver",
                         config=tb.StageConfig(merge_excursion=3.0))
    assert overshoot["lateral"].item() == "Straight > Left Turn > Right Turn > Straight"
    for name in ("merge_heading", "merge_offset", "merge_excursion", "merge_gap"):
        with pytest.raises(tb.TapBenchError, match=name):
            tb.StageConfig(**{name: -1.0})


def test_a_right_lane_change_is_never_a_left_merge():
    # the sideways move must go to the first turn's side: mirror the shape of a left lane
    # change's heading but not its positions, and it cannot merge
    table = tb.behaviour("left_lane_change")
    table["y"] = -table["y"]  # the car moves right while its heading turns left, then right
    got = tb.label(table, level="maneuver")["lateral"].item()
    assert "Merge" not in got


# -- lane changes the end of the data cut off (SPEC 4.3: a lane change and its return on a
# straight road are merges). At 15 m/s; a turn of yaw w starting at step s reads w/2 at s
# (Straight when w/2 cancels against the turn before it) and the last step reads a
# one-sided difference, the yaw commanded the step before it.
def left_lane_change_with_partial_return(side: int = +1) -> pd.DataFrame:
    """1 s straight, a lane change towards ``side`` (0.12 rad/s for 1.5 s out, 1.5 s back),
    3 s straight in the new lane, then the lane change back: 1.5 s at -0.12 and 0.6 s of
    its straightening at +0.12 when the data ends (9.1 s)."""
    yaw = side * np.concatenate([np.zeros(10), np.full(15, 0.12), np.full(15, -0.12),
                                 np.zeros(30), np.full(15, -0.12), np.full(6, 0.12)])
    return from_controls(np.full(91, 15.0), yaw, track_id="partial_return")


def lane_change_and_partial_return_at_once() -> pd.DataFrame:
    """2 s straight, 1.5 s at +0.12 rad/s, 3 s at -0.12 (the first lane change's
    straightening and, without a break, the way back), 0.6 s of +0.12 when the data ends
    (7.1 s)."""
    yaw = np.concatenate([np.zeros(20), np.full(15, 0.12), np.full(30, -0.12),
                          np.full(6, 0.12)])
    return from_controls(np.full(71, 15.0), yaw, track_id="at_once")


@pytest.mark.parametrize("side", [+1, -1])
def test_a_lane_change_and_its_partial_return_are_two_merges(side):
    """Worked by hand for side +1. Trace: Left 10-24 (step 10 reads 0.06), Straight 25
    (0.12 - 0.12), Right 26-40 (step 40 reads -0.06), Straight 41-69, Right 70-84, Straight
    85, Left 86-90 (the last step one-sided, 0.12). Trend: step 25 joins the earlier of its
    two 15-step neighbours (Left); steps 85-90 (their 1 s window 81-90 means +0.012:
    Straight, still short) join the Right run: Left 10-25, Right 26-40, Straight, Right
    70-90. Maneuver: the first pair comes back to heading 0 and moves 4.04 m left (y 0 at
    step 10 to 4.04 at 40): Left Merge. The last Right run ends the data while its trace
    turns back (Left 86-90, four of them central differences): that turn back is its
    second turn. Over 70-90 the heading goes to -0.18 and back to -0.12 rad (net 0.12 <=
    0.2, never beyond pi/6) and the car moves 3.05 m right (y 4.04 to 0.99, >= 1.5): a Right
    Merge, not a Turn. 15 m/s: Medium."""
    table = left_lane_change_with_partial_return(side)
    if side < 0:
        first, back = "Right", "Left"
    else:
        first, back = "Left", "Right"
    got = labels_of(table)
    assert got["trend"] == (f"Straight > {first} Turn > {back} Turn > Straight > {back} Turn"
                            " | Maintain Speed")
    assert got["maneuver"] == (f"Straight > {first} Merge > Straight > {back} Merge"
                               " | Maintain Speed")
    assert got["action"] == (f"Straight > {first} Merge > Straight > {back} Merge"
                             " | Maintain Medium Speed")


def test_a_lane_change_with_its_partial_return_at_once_is_two_merges():
    """Trace: Left 20-34, Straight 35, Right 36-64, Straight 65, Left 66-70. Trend: step 35
    (window 31-40 means -0.012) joins its longer neighbour, the 29-step Right run; steps
    65-70 (window 61-70, +0.012) join it too: Left 20-34, Right 35-70. Maneuver: with the
    turn back at 66-70 as its second turn, Left, Right, Left is a chain: the heading is back
    at 0 half-way through the Right run (at step 50, 1e-17 above it in floats: the first
    step past it is 51, with 15 steps of the run left), Left 20-50 moves 4.04 m left and
    Right 51-70 comes back to -0.12 rad and 3.05 m right: two merges. Before,
    the Left and the whole Right run were one pair that ends 1 m from where it started: a
    wiggle, and the two lane changes read Straight."""
    got = labels_of(lane_change_and_partial_return_at_once())
    assert got["trend"] == "Straight > Left Turn > Right Turn | Maintain Speed"
    assert got["maneuver"] == "Straight > Left Merge > Right Merge | Maintain Speed"


@pytest.mark.parametrize("case, yaw, maneuver", [
    # the way back cut before it turns back (2.1 s at -0.12, still turning): a turn is all
    # the data shows
    ("cut_while_turning", [(10, 0.0), (15, 0.12), (15, -0.12), (30, 0.0), (21, -0.12)],
     "Straight > Left Merge > Straight > Right Turn"),
    # the turn back only in the last step, a one-sided difference (step 89 reads
    # (-0.12 + 0.12) / 2 = 0): not enough to see it turn back
    ("back_in_the_last_step_only", [(10, 0.0), (15, 0.12), (15, -0.12), (30, 0.0),
                                     (19, -0.12), (2, 0.12)],
     "Straight > Left Merge > Straight > Right Turn"),
    # a 0.48 rad right turn straightening for 0.6 s when the data ends: the heading does not
    # come back within 0.2 rad
    ("turn_straightening", [(45, 0.0), (40, -0.12), (6, 0.12)], "Straight > Right Turn"),
])
def test_a_turn_the_data_cuts_off_stays_a_turn(case, yaw, maneuver):
    yaw = np.concatenate([np.full(n, w) for n, w in yaw])
    got = labels_of(from_controls(np.full(91, 15.0), yaw, track_id=case))
    assert got["maneuver"] == maneuver + " | Maintain Speed"
