"""Small WOMD files for the closed-loop tests, written with the project's own writer
(:func:`tap_bench.womd.writer.encode_scenarios`): a straight-lane scene as a trajectory
table, its map appended as WOMD's map.proto encodes it, and bad values set in the decoded
``Scenario`` proto (``spoil``)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from tap_bench.womd import proto
from tap_bench.womd.tfrecord import TFRecordWriter
from tap_bench.womd.writer import encode_scenarios

T = np.round(np.arange(91) * 0.1, 10)


def straight_scene(sid: str, *, angle: float = 0.3) -> pd.DataFrame:
    """A 9.1 s scene: the ego (track 1) at 10 m/s along a straight lane heading ``angle``,
    a car (track 2) 25 m ahead at 11 m/s."""
    c, s = np.cos(angle), np.sin(angle)
    rows = []
    for track, start, speed, ego in ((1, 0.0, 10.0, True), (2, 25.0, 11.0, False)):
        lon = start + speed * T
        rows.append(pd.DataFrame({
            "scenario_id": sid, "track_id": str(track), "t": T, "x": lon * c, "y": lon * s,
            "heading": angle, "vx": speed * c, "vy": speed * s, "valid": True,
            "object_type": "vehicle", "is_ego": ego, "length": 4.5, "width": 2.0,
            "height": 1.5}))
    return pd.concat(rows, ignore_index=True)


def lane_map(points: np.ndarray, lane_id: int = 100) -> bytes:
    """A map of one lane (its centre line ``points``), as a Scenario's map features."""
    lane = proto.ScenarioMapView()
    feature = lane.map_features.add(id=lane_id)
    for x, y in points:
        feature.lane.polyline.add(x=float(x), y=float(y), z=0.0)
    return lane.SerializeToString()


def straight_lane(angle: float = 0.3) -> np.ndarray:
    lon = np.arange(-20.0, 180.0, 2.0)
    return np.c_[lon * np.cos(angle), lon * np.sin(angle)]


def record(table: pd.DataFrame, *, lane: np.ndarray | None = None,
           spoil: Callable[[proto.Scenario], None] | None = None) -> bytes:
    """A Scenario record of ``table`` (the writer's), ``spoil`` applied to its proto, with
    a map of one lane appended."""
    (_, data), = encode_scenarios(table)
    if spoil is not None:
        scenario = proto.Scenario.FromString(data)
        spoil(scenario)
        data = scenario.SerializeToString()
    return data + lane_map(straight_lane() if lane is None else lane)


def womd_file(path: Path, *records: bytes) -> str:
    with TFRecordWriter(path) as writer:
        for data in records:
            writer.write(data)
    return str(path)


def set_state(track: int, step: int, **values: float) -> Callable[[proto.Scenario], None]:
    def spoil(scenario: proto.Scenario) -> None:
        state = scenario.tracks[track].states[step]
        for name, value in values.items():
            setattr(state, name, value)
    return spoil


def set_time(step: int, value: float) -> Callable[[proto.Scenario], None]:
    def spoil(scenario: proto.Scenario) -> None:
        scenario.timestamps_seconds[step] = value
    return spoil
