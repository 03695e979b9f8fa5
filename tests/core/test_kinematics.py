"""Kinematics: finite differences within segments, unwrapping, one-second distributions."""

from __future__ import annotations

import numpy as np
import pandas as pd

import tap_bench as tb
from tap_bench.kinematics import compute_kinematics, one_second_samples
from tap_bench.synthetic import from_controls
from tap_bench.trajectories import validate_and_index


def kinematics(table: pd.DataFrame):
    return compute_kinematics(validate_and_index(table))


def test_constant_yaw_rate_and_acceleration_are_recovered():
    speed = 5.0 + 2.0 * 0.1 * np.arange(50)
    kin = kinematics(from_controls(speed, np.full(50, 0.2)))
    assert np.allclose(kin.w[1:], 0.2)  # the first step's one-sided difference too
    assert np.allclose(kin.a, 2.0)


def test_heading_is_unwrapped_across_pi():
    # heading crosses from +pi to -pi while turning left at 0.5 rad/s
    kin = kinematics(from_controls(np.full(40, 5.0), np.full(40, 0.5), heading0=3.0))
    assert np.allclose(kin.w[1:], 0.5)


def test_derivatives_do_not_cross_gaps_or_tracks():
    a = from_controls(np.full(20, 5.0), np.zeros(20), track_id="a").assign(valid=True)
    a.loc[10, "valid"] = False
    a.loc[10, "heading"] = 3.0  # garbage on an invalid row must not leak
    b = from_controls(np.full(20, 30.0), np.full(20, -0.1), track_id="b").assign(valid=True)
    kin = kinematics(pd.concat([a, b], ignore_index=True))
    assert np.isnan(kin.w[10]) and np.isnan(kin.a[10])
    assert np.allclose(kin.w[:10], 0.0) and np.allclose(kin.w[11:20], 0.0)
    assert np.allclose(kin.a[:20][~np.isnan(kin.a[:20])], 0.0)
    assert np.allclose(kin.w[21:], -0.1)


def test_one_step_segment_has_zero_derivatives():
    table = from_controls(np.full(3, 5.0), np.full(3, 0.3)).assign(valid=[True, False, True])
    kin = kinematics(table)
    assert kin.w[0] == 0.0 and kin.a[2] == 0.0


def test_one_second_samples_are_non_overlapping_window_means():
    speed = np.arange(35, dtype=float)  # 35 steps: three full windows, 5 steps left out
    samples = one_second_samples(from_controls(speed, np.full(35, -0.2)))
    assert np.allclose(samples["v"], [4.5, 14.5, 24.5])
    assert np.allclose(samples["w"][1:], 0.2)  # |w|
    assert np.allclose(samples["a"], 10.0)


def test_samples_count_per_segment():
    table = tb.random_trajectories(20, steps=91, seed=3)
    samples = one_second_samples(table)
    assert len(samples["v"]) == 20 * 9
    moving = samples["v"] > 0.1  # stopped windows are left out of D_a and D_w (SPEC 3)
    assert len(samples["a"]) == moving.sum() < 20 * 9
    assert len(samples["w"]) <= moving.sum()  # and windows whose heading is untrusted


def _headings_by_track(table: pd.DataFrame) -> dict:
    checked = validate_and_index(table)
    heading = compute_kinematics(checked).heading
    keys = pd.DataFrame({"scenario_id": np.asarray(checked["scenario_id"]),
                         "track_id": np.asarray(checked["track_id"])})
    return {key: heading[rows] for key, rows in keys.groupby(
        ["scenario_id", "track_id"], sort=False).indices.items()}


def test_a_tracks_heading_has_the_bits_it_has_alone():
    """The heading is unwrapped by summing each step's repaired change from the segment's
    start; summed over the whole table, a track's headings were rounded by the sum of every
    track before it, so an episode labelled in a batch (bench run) or a file labelled in parts
    (tap-bench label) had other heading bits than alone, and the built-in sample's
    'two_lane_changes' changed lanes at 5.0 s in its scenario and at 5.1 s alone. Drawn
    tables of 20 tracks (summed one by one) and of 150 (summed as 2-D arrays: lengths many
    tracks share, and the other lengths padded to powers of two), tracks of 1 to 300 steps,
    circling tracks that pile up tens of radians, invalid rows, several scenarios."""
    rng = np.random.default_rng(7)
    compared = 0
    for seed, n_tracks in enumerate([20, 150, 150, 20]):  # each size with, without gaps
        table = tb.random_trajectories(n_tracks, 300, seed=seed, scenarios=3)
        code = pd.factorize(table["track_id"])[0]
        keep = np.where(rng.random(n_tracks) < 0.5, 300, rng.integers(1, 301, n_tracks))
        step = table.groupby("track_id", sort=False).cumcount().to_numpy()
        table, code, step = (table[step < keep[code]].reset_index(drop=True),
                             code[step < keep[code]], step[step < keep[code]])
        circling = code % 3 == 0
        turned = table.loc[circling, "heading"] + 0.25 * step[circling]  # 2.5 rad/s
        table.loc[circling, "heading"] = np.angle(np.exp(1j * turned))
        if seed % 2:
            table["valid"] = rng.random(len(table)) > 0.03
        together = _headings_by_track(table)
        for (scenario, track), heading in together.items():
            alone = _headings_by_track(table[(table["scenario_id"] == scenario)
                                             & (table["track_id"] == track)])
            np.testing.assert_array_equal(heading, alone[(scenario, track)],
                                          err_msg=f"seed {seed} track {track}")
            compared += 1
    assert compared > 300


def test_the_sample_changes_lanes_at_one_time_alone_and_in_its_scenario():
    """The track the old whole-table sum mislabelled (see above), alone and in its
    scenario: the same step labels."""
    sample = tb.sample_table(n_random=0)
    scene = sample[sample["scenario_id"] == "behaviours"]
    track = scene[scene["track_id"] == "two_lane_changes"]
    steps = [tb.tap(t).steps() for t in (scene, track)]
    steps = [s[s["track_id"] == "two_lane_changes"].reset_index(drop=True) for s in steps]
    pd.testing.assert_frame_equal(steps[0], steps[1], check_exact=True)
