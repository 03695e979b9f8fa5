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
