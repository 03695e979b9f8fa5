"""The four real WOMD samples (skipped when absent) written to Parquet, read with their
strings encoded and labelled in parts, as the command line labels a large file: every
table equal to tap() of the file as read_table reads it."""

from __future__ import annotations

import warnings

import pytest

from tap_bench.labelling import tap, tap_in_parts
from tap_bench.tableio import EncodedTable, read_table, read_table_encoded

from ..core.test_tap_in_parts import _assert_same

pytestmark = pytest.mark.womd
FILES = ("motion_data_one_scenario.tfrecord", "womd_scenario_input.tfrecord",
         "motion_data_one_example.tfrecord", "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl")


@pytest.mark.parametrize("interactions", [None, "ego", "all"])
def test_real_scenes_encoded_give_the_tables_of_one_call(womd_dir, tmp_path, interactions):
    from tap_bench.sources.ingest import read_womd

    table = read_womd([womd_dir / f for f in FILES])
    table = table.sort_values("scenario_id", kind="stable").reset_index(drop=True)
    path = tmp_path / "womd.parquet"
    table.to_parquet(path)
    encoded = read_table_encoded(path, 0)
    assert isinstance(encoded, EncodedTable)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        whole = tap(read_table(path), interactions=interactions)
        parts = tap_in_parts(encoded, part_rows=1, interactions=interactions)
    assert len(parts.parts) == table["scenario_id"].nunique() == 4
    _assert_same(parts, whole)
