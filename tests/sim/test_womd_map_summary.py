"""A rollout over many recorded scenes warns about their maps once: a MapWarning per scene
(each with its code line) flooded a real shard's output."""

from __future__ import annotations

import pickle
import warnings
from pathlib import Path

import numpy as np

from tap_bench.sim.rollout import rollout
from tap_bench.sim.womd_env import MapWarning, map_summary
from tap_bench.sim.womd_scene import WomdScenes


def scene_with_a_one_point_lane(path: Path, one_point: bool = True) -> str:
    """A ScenarioNet pickle: a 130 m straight lane and the ego on it at 10 m/s for 9 s,
    and (``one_point``) a lane of a single point, which the road network leaves out."""
    t = np.arange(91) * 0.1
    ego = {"type": "VEHICLE", "state": {
        "position": np.c_[10.0 * t, np.zeros(91), np.zeros(91)], "heading": np.zeros(91),
        "velocity": np.c_[np.full(91, 10.0), np.zeros(91)], "valid": np.ones(91, bool),
        "length": np.full(91, 4.5), "width": np.full(91, 2.0)}}
    features = {"1": {"type": "LANE_SURFACE_STREET",
                      "polyline": np.c_[np.arange(-10, 120, 0.5), np.zeros(260)],
                      "entry_lanes": [], "exit_lanes": []}}
    if one_point:
        features["2"] = {"type": "LANE_SURFACE_STREET", "polyline": np.array([[5.0, 5.0]])}
    with path.open("wb") as f:
        pickle.dump({"metadata": {"scenario_id": path.stem, "ts": t, "dataset": "waymo",
                                  "sdc_id": "ego"},
                     "tracks": {"ego": ego}, "map_features": features,
                     "dynamic_map_states": {}}, f)
    return str(path)


def test_a_rollout_over_scenes_warns_once_about_their_maps(tmp_path, monkeypatch):
    monkeypatch.setattr("tap_bench.sim.womd_env._WARNED", set())  # as in a fresh process
    files = [scene_with_a_one_point_lane(tmp_path / f"sd_map{i}.pkl", one_point=i < 3)
             for i in range(4)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = rollout(WomdScenes(tuple(files)), "log", "all", duration=1.0, record=False)
    maps = [w for w in caught if issubclass(w.category, MapWarning)]
    assert len(maps) == 1, [str(w.message) for w in maps]
    text = str(maps[0].message)
    # every one names no entry or exit lanes: successors inferred; three have a one-point lane
    assert "4 of 4 recorded scene(s)" in text and "4 with successors inferred" in text
    assert "3 with lanes of a single point" in text
    assert "'map' column" in text and "\n" not in text
    assert result.episodes["map"].str.contains("left out").sum() == 3


def test_map_summary_counts_how_the_maps_changed():
    notes = ["12 lanes", "9 lanes; successors inferred from lane ends that meet (4 links; "
             "the data names no entry or exit lanes)",
             "3 lanes; successors inferred from lane ends that meet (1 links; ...); 1 lane(s) "
             "of a single point left out (7)", None]
    line = map_summary(notes)
    assert line.startswith("the map of 2 of 3 recorded scene(s) was completed or trimmed")
    assert "2 with successors inferred" in line and "1 with lanes of a single point" in line
    assert map_summary(["12 lanes", "4 lanes"]) is None
