"""The sim-to-real behaviour gap on label tables small enough to check by hand."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.bootstrap import BootstrapConfig
from tap_bench.bench.gap import behaviour_gap, labelled_with_speed
from tap_bench.errors import LabelTableError


def labels(rows, speed=None):
    out = pd.DataFrame(rows, columns=["lateral", "longitudinal", "interaction"])
    out["mean_speed"] = np.nan if speed is None else speed
    return out


def test_gap_by_hand():
    # policy: 10 trajectories "Straight | Maintain Speed | Following" (3 label occurrences
    # each: shares 1/3, 1/3, 1/3); reference: 10 with Following, 10 with Free Driving
    # (shares: Straight 1/3, Maintain Speed 1/3, Following 1/6, Free Driving 1/6)
    pol = labels([("Straight", "Maintain Speed", "Following")] * 10)
    ref = labels([("Straight", "Maintain Speed", "Following")] * 10
                 + [("Straight", "Maintain Speed", "Free Driving")] * 10)
    result = behaviour_gap(pol, ref, config=BootstrapConfig(n_resamples=500))
    assert result.gap == pytest.approx(1 / 6)  # 0.5 * (1/6 + 1/6)
    table = result.labels.set_index("label")
    assert table.loc["Following", "diff"] == pytest.approx(1 / 6)
    assert table.loc["Free Driving", "diff"] == pytest.approx(-1 / 6)
    assert table.loc["Straight", "diff"] == pytest.approx(0)
    assert 0.5 * table["diff"].abs().sum() == pytest.approx(result.gap)  # it decomposes
    assert result.gap_low <= result.gap <= result.gap_high
    # a policy drawn from the reference itself sits near its floor
    same = behaviour_gap(ref, ref, config=BootstrapConfig(n_resamples=500))
    assert same.gap == 0 and same.floor > 0


def test_comparable_situations_by_speed_and_errors():
    pol = labels([("Straight", "Maintain Speed", "Following")] * 4, speed=[22.0, 24, 26, 28])
    ref = labels([("Straight", "Maintain Speed", "Following")] * 3
                 + [("Left Turn", "Decelerate", "Free Driving")] * 3,
                 speed=[25, 26, 24, 5, 6, 4])
    result = behaviour_gap(pol, ref, config=BootstrapConfig(n_resamples=200))
    assert result.n_reference == 3 and result.gap == 0  # only the fast ones compared
    assert "22.3 to 27.7 m/s" in result.reference  # the policy's 5 % and 95 % quantiles
    with pytest.raises(LabelTableError, match="nothing to compare"):
        behaviour_gap(pol, ref, min_speed=30.0)


def test_labelled_with_speed_gives_each_trajectorys_mean_speed():
    t = np.arange(30) / 10
    table = pd.DataFrame({"scenario_id": "s", "track_id": np.repeat(["a", "b"], 30),
                          "t": np.tile(t, 2), "x": np.r_[10 * t, 20 * t], "y": 0.0,
                          "heading": 0.0, "speed": np.repeat([10.0, 20.0], 30),
                          "is_ego": np.repeat([True, False], 30)})
    out = labelled_with_speed(table, "maneuver", interactions="all")
    assert list(out["mean_speed"]) == pytest.approx([10.0, 20.0])
    assert out["interaction"].notna().all()
