"""Fixtures for the distributed tests: writer-made WOMD shards (the Ray cluster,
``ray_backend``, is the suite's: tests/conftest.py)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest


def _shard_table(i: int) -> pd.DataFrame:
    from tap_bench import random_trajectories

    table = random_trajectories(30, seed=i, scenarios=3)
    table["scenario_id"] = f"shard{i}-" + table["scenario_id"].astype(str)
    return table


@pytest.fixture(scope="package")
def womd_shards(tmp_path_factory) -> tuple[list[Path], pd.DataFrame]:
    """Three WOMD TFRecord shards written from random trajectories (distinct scenarios), and
    the table they hold."""
    from tap_bench.womd.writer import write_womd

    folder = tmp_path_factory.mktemp("womd")
    tables, paths = [], []
    for i in range(3):
        table = _shard_table(i)
        paths.append(write_womd(table, folder / f"training.tfrecord-{i:05d}-of-00003"))
        tables.append(table)
    return paths, pd.concat(tables, ignore_index=True)
