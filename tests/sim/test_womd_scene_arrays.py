"""A decoded scene checked on its Arrow arrays (``womd_scene._keeps_contract``) instead of
through a pandas table: a table it passes keeps the trajectory contract (every spoilt table
below that the contract refuses, it refuses too, and pandas then names the problem), and the
scene made from the arrays is the scene made through pandas, field for field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from tap_bench.errors import TrajectoryTableError
from tap_bench.sim import womd_scene
from tap_bench.sim.womd_scene import load_scene, scene_catalog
from tap_bench.trajectories import plainly_valid, validate_and_index
from tap_bench.womd.scenario import trajectory_table

N_TRACKS, N_STEPS = 3, 20


def _table(**spoil) -> pa.Table:
    """A clean decoded table of three tracks, then ``spoil`` applied to its columns."""
    times = 0.1 * np.arange(N_STEPS) + 0.0002 * np.arange(N_STEPS)
    rows = N_TRACKS * N_STEPS
    rng = np.random.default_rng(3)
    states = {"x": rng.normal(0, 50, rows), "y": rng.normal(0, 50, rows),
              "z": np.zeros(rows), "heading": rng.uniform(-3, 3, rows),
              "vx": rng.normal(0, 5, rows), "vy": rng.normal(0, 5, rows),
              "length": np.full(rows, 4.5), "width": np.full(rows, 2.0),
              "height": np.full(rows, 1.5), "valid": np.arange(rows) % 7 != 3}
    table = trajectory_table("s", times, ["7", "11", "3"], ["vehicle", "pedestrian", "other"],
                             states, is_ego=np.array([True, False, False]),
                             object_of_interest=np.zeros(3, bool),
                             track_to_predict=np.zeros(3, bool),
                             prediction_difficulty=np.zeros(3, np.int8), source="womd")
    for name, change in spoil.items():
        values = table.column(name).to_numpy(zero_copy_only=False).copy()
        change(values)
        table = table.set_column(table.schema.get_field_index(name), name,
                                 pa.array(values, type=table.schema.field(name).type))
    return table


def _at(row: int, value):
    def change(values):
        values[row] = value
    return change


SPOILT = {
    "nan x on a valid row": {"x": _at(5, np.nan)},
    "nan x on an invalid row": {"x": _at(3, np.nan)},
    "infinite y": {"y": _at(8, np.inf)},
    "infinite vx on an invalid row": {"vx": _at(3, -np.inf)},
    "far off": {"x": _at(9, 2e7)},
    "far off, invalid": {"x": _at(10, 2e7), "valid": _at(10, False)},
    "too fast": {"speed": _at(11, 150.0)},
    "negative speed": {"speed": _at(12, -1.0)},
    "heading in degrees": {"heading": _at(13, 90.0)},
    "nan time": {"t": _at(14, np.nan)},
    "time going back": {"t": _at(15, 0.5)},
    "a time twice": {"t": lambda t: t.__setitem__(16, t[15])},
    "a gap of whole steps": {"t": lambda t: t.__setitem__(slice(25, 40), t[25:40] + 0.2)},
    "an irregular step": {"t": lambda t: t.__setitem__(slice(25, 40), t[25:40] + 0.05)},
    "a track in two runs": {"track_id": lambda v: v.__setitem__(slice(50, 60), "7")},
    "two scenarios": {"scenario_id": lambda v: v.__setitem__(slice(40, 60), "s2")},
    "a type in capitals": {"object_type": lambda v: v.__setitem__(slice(0, 20), "Vehicle")},
    "an unknown type": {"object_type": lambda v: v.__setitem__(slice(20, 40), "truck")},
}


def test_a_clean_table_is_read_from_its_arrays():
    table = _table()
    assert womd_scene._keeps_contract(table)
    validate_and_index(table.to_pandas())


@pytest.mark.parametrize("case", sorted(SPOILT))
def test_what_the_arrays_pass_keeps_the_contract(case):
    table = _table(**SPOILT[case])
    try:
        validate_and_index(table.to_pandas())
        keeps = True
    except TrajectoryTableError:
        keeps = False
    for passed in (womd_scene._keeps_contract(table), plainly_valid(table),
                   plainly_valid(table.to_pandas())):
        assert keeps or not passed, case


def test_a_frame_of_other_column_types_goes_through_pandas():
    frame = _table().to_pandas()
    assert plainly_valid(frame)
    assert not plainly_valid(frame.astype({"track_id": object}))
    assert not plainly_valid(frame.astype({"x": "float32"}))
    assert not plainly_valid(frame.astype({"valid": "boolean"}))
    assert not plainly_valid(frame.rename(columns={"y": "x"}))
    assert not plainly_valid(frame.drop(columns="valid"))
    assert not plainly_valid(frame.iloc[:0])
    assert plainly_valid(frame.drop(columns=["object_type", "is_ego"]))


@pytest.mark.womd
def test_a_rollouts_episode_tables_are_read_from_their_arrays(tmp_path):
    dev = next(r.path for r in _real_refs() if r.path.endswith("dev.tfrecord"))
    from tap_bench.sim.rollout import rollout

    tables, _ = rollout(womd_scene.WomdScenes(dev), "idm", "0-1", progress=False)
    for _, table in tables.groupby("seed"):
        table = table.reset_index(drop=True)
        assert plainly_valid(table)
        validate_and_index(table)


def test_a_table_with_nulls_or_other_types_goes_through_pandas():
    table = _table()
    with_null = table.set_column(3, "x", pa.array([None, *table.column("x").to_pylist()[1:]],
                                                  type=pa.float64()))
    assert not womd_scene._keeps_contract(with_null)
    as_float32 = table.set_column(3, "x", table.column("x").cast(pa.float32()))
    assert not womd_scene._keeps_contract(as_float32)
    assert not womd_scene._keeps_contract(table.slice(0, 0))


def _real_refs() -> list:
    root = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
    files = [root / "womd", root / "womd-dev" / "dev.tfrecord"]
    if not all(f.exists() for f in files):
        pytest.skip("real WOMD samples not found")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return scene_catalog([str(f) for f in files])


def _assert_same_scene(a, b) -> None:
    assert type(a.track_ids) is type(b.track_ids) and a.track_ids.dtype == b.track_ids.dtype
    assert list(a.track_ids) == list(b.track_ids)
    for name in ("scenario_id", "ref", "digest", "ego", "road"):
        assert getattr(a, name) is getattr(b, name) or getattr(a, name) == getattr(b, name)
    for name in ("times", "object_types", "x", "y", "heading", "vx", "vy", "speed", "valid",
                 "length", "width"):
        mine, theirs = getattr(a, name), getattr(b, name)
        assert mine.dtype == theirs.dtype and mine.shape == theirs.shape, name
        assert np.array_equal(mine, theirs, equal_nan=mine.dtype.kind == "f"), name


@pytest.mark.womd
def test_real_scenes_from_arrays_equal_the_scenes_through_pandas(monkeypatch):
    refs = _real_refs()
    assert len(refs) >= 12
    seen: list[bool] = []
    keeps = womd_scene._keeps_contract
    monkeypatch.setattr(womd_scene, "_keeps_contract",
                        lambda table: seen.append(keeps(table)) or seen[-1])
    fast = [load_scene(ref) for ref in refs]
    assert seen == [True] * len(refs)  # every real scene read from its arrays
    monkeypatch.setattr(womd_scene, "_keeps_contract", lambda table: False)
    for ref, scene in zip(refs, fast, strict=True):
        slow = load_scene(ref)
        object.__setattr__(slow, "road", scene.road)  # the maps are compared elsewhere
        _assert_same_scene(scene, slow)


@pytest.mark.womd
def test_a_streamed_episode_table_that_breaks_the_contract_is_not_written(tmp_path,
                                                                         monkeypatch):
    from tap_bench.sim import womd_env
    from tap_bench.sim.rollout_stream import stream_rollout

    dev = next(r.path for r in _real_refs() if r.path.endswith("dev.tfrecord"))
    made = womd_env.WomdEnv.trajectories

    def spoilt(self, **columns):
        table = made(self, **columns)
        row = int(np.flatnonzero(table["valid"].to_numpy())[3])
        table.loc[row, "heading"] = 9.0  # beyond 2 pi on a valid row
        assert not plainly_valid(table)
        return table

    monkeypatch.setattr(womd_env.WomdEnv, "trajectories", spoilt)
    with pytest.raises(TrajectoryTableError, match=r"seed 0, not written.*heading 9\.0"):
        stream_rollout(womd_scene.WomdScenes(dev), "idm", "0", tmp_path / "out.parquet",
                       progress=False)
