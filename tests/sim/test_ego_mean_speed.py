"""rollout's episode row: the ego's mean speed computed without pandas' selection gives
pandas' own ``table.loc[table["is_ego"], "speed"].mean()`` (the same sum of the same
values, divided by the same count), within float rounding."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tap_bench.sim.rollout import ego_mean_speed


def pandas_mean(table: pd.DataFrame) -> float:
    return float(table.loc[table["is_ego"].to_numpy(), "speed"].mean())


@pytest.mark.parametrize("seed", range(8))
def test_the_ego_mean_speed_is_pandas_mean(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 3000))
    speed = rng.normal(8.0, 5.0, n) * 10.0 ** rng.uniform(-3, 3, n)
    speed[rng.random(n) < rng.uniform(0, 0.5)] = np.nan
    table = pd.DataFrame({"speed": speed, "is_ego": rng.random(n) < rng.uniform(0, 1)})
    want, got = pandas_mean(table), ego_mean_speed(table)
    # the same sum of the same values; a tolerance, not pandas' rounding bit for bit
    np.testing.assert_allclose(got, want, rtol=1e-12, equal_nan=True)


def test_no_ego_row_or_only_nan_speeds_give_nan():
    table = pd.DataFrame({"speed": [1.0, np.nan, 3.0], "is_ego": [False, True, False]})
    assert np.isnan(ego_mean_speed(table)) and np.isnan(pandas_mean(table))
    table["is_ego"] = False
    assert np.isnan(ego_mean_speed(table)) and np.isnan(pandas_mean(table))


def test_other_column_types_take_pandas_path():
    table = pd.DataFrame({"speed": pd.array([1.0, None, 4.0], dtype="Float64"),
                          "is_ego": pd.array([True, True, True], dtype="boolean")})
    assert ego_mean_speed(table) == pandas_mean(table) == 2.5
