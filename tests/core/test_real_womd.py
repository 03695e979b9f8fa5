"""The TAP core on the real WOMD files of ../shared/data/womd (skipped when absent)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import tap_bench as tb
from tap_bench.trajectories import validate_and_index

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "womd"
FILES = ["motion_data_one_scenario.tfrecord", "womd_scenario_input.tfrecord"]

pytestmark = pytest.mark.womd


@pytest.fixture(scope="module")
def vehicles():
    if not all((DATA / f).is_file() for f in FILES):
        pytest.skip(f"real WOMD files not found in {DATA}")
    read_womd = pytest.importorskip("tap_bench.sources.ingest").read_womd
    table = read_womd([DATA / f for f in FILES])
    return table[table["object_type"] == "vehicle"].reset_index(drop=True)


def test_real_scenarios_label_at_every_level(vehicles):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", tb.ShortSegmentWarning)
        result = tb.tap(vehicles)
    labels = result.labels("all")
    assert set(labels["scenario_id"]) == {"637f20cafde22ff8", "ee519cf571686d19"}
    # 70 + 189 vehicle tracks; every labelled segment has four rows
    assert len(labels) == 4 * len(result.segments_info)
    assert result.segments_info["n_steps"].min() >= 10
    # segments too short to label are reported, not lost
    total = len(result.segments_info) + len(result.short_segments)
    assert total == validate_and_index(vehicles).index.n_segments
    # the SDC of the first scenario is labelled
    ego = labels[(labels["is_ego"]) & (labels["level"] == "action")]
    assert "637f20cafde22ff8" in set(ego["scenario_id"])


def test_parked_vehicles_are_stopped(vehicles):
    result = tb.tap(vehicles)
    labels = result.labels("trend")
    speed = vehicles.groupby(["scenario_id", "track_id"])["speed"].max()
    parked = speed[speed < 0.05].index
    assert len(parked) > 10
    got = labels.set_index(["scenario_id", "track_id"]).loc[
        labels.set_index(["scenario_id", "track_id"]).index.isin(parked), "sdl"]
    assert (got == "Straight | Stopped").all()


def test_one_second_samples_and_fit_on_real_data(vehicles):
    samples = tb.one_second_samples(vehicles)
    segs = validate_and_index(vehicles).index
    assert len(samples["v"]) == int((segs.segment_length // 10).sum())
    report = tb.fit_report(samples, methods=("descent", "grid"))
    for dist in ("w", "a", "v"):
        assert np.isfinite(report.fits[dist].chosen.objective)


def test_glitches_of_the_real_files_are_repaired_and_counted(vehicles):
    result = tb.tap(vehicles)
    labels = result.labels("all")
    # ee519cf571686d19 track 916 (issue 12): parked, 0.3 m of travel, heading flipping
    # between -0.29 and 2.87 rad, speed spiking to 12 m/s: once "Aggressive Right Turn |
    # Accelerate Slow Speed"
    parked = labels[(labels["scenario_id"] == "ee519cf571686d19")
                    & (labels["track_id"] == "916")].set_index("level")
    assert set(parked["lateral"]) == {"Straight"}
    assert parked.loc["action", "longitudinal"] == "Maintain Slow Speed"
    assert parked.loc["action", "heading_glitches"] == 3
    assert parked.loc["action", "speed_glitches"] == 5
    assert parked.loc["action", "travel"] < 1.0
    # no vehicle that travels less than 1 m carries a turn or merge, at any level
    still = labels[labels["travel"] < 1.0]
    assert len(still) > 4 * 100
    assert not still["lateral"].str.contains("Turn|Merge").any()
    # the report per track adds them up over every valid segment, short ones included
    report = result.glitches()
    every = pd.concat([result.segments_info, result.short_segments])
    assert report["heading_glitches"].sum() == every["heading_glitches"].sum() > labels.loc[
        labels["level"] == "action", "heading_glitches"].sum()
    assert (report["speed_glitches"] > 0).sum() > 10
