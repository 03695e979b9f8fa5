"""The viewer's documents and the map tables they draw, on cases small enough to check by
hand."""

from __future__ import annotations

import base64
import json

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.report.viewer.data import (
    MISSING,
    clip_polyline,
    encode_int16,
    episode_chunks,
    episode_index,
    map_features,
)
from tap_bench.errors import FileFormatError
from tap_bench.maps import check_map_table


def _int16(text: str) -> np.ndarray:
    return np.frombuffer(base64.b64decode(text), dtype="<i2")


def test_clip_polyline_by_hand():
    box = (0.0, 0.0, 10.0, 10.0)
    # a horizontal line through the box, from x -5 to 15: clipped to 0..10
    (piece,) = clip_polyline(np.array([[-5.0, 5.0], [15.0, 5.0]]), box)
    assert piece.tolist() == [[0.0, 5.0], [10.0, 5.0]]
    # in, out, in again: two pieces
    pieces = clip_polyline(np.array([[1.0, 1.0], [1.0, 20.0], [5.0, 20.0], [5.0, 1.0]]), box)
    assert [p.tolist() for p in pieces] == [[[1.0, 1.0], [1.0, 10.0]], [[5.0, 10.0], [5.0, 1.0]]]
    # wholly outside: nothing
    assert clip_polyline(np.array([[20.0, 20.0], [30.0, 30.0]]), box) == []


def test_highway_road_is_three_four_metre_lanes():
    from tap_bench.sim.roads import road_table

    roads = check_map_table(road_table("highway"))
    lanes = roads[roads["kind"] == "lane"]
    assert lanes["feature_id"].nunique() == 3 and (lanes["width"] == 4.0).all()
    # highway-env's lanes are at y 0, 4, 8 m to the driver's right: 0, -4, -8 in Waymo axes
    assert sorted(lanes.groupby("feature_id")["y"].first()) == [-8.0, -4.0, 0.0]
    lines = roads[roads["kind"] == "road_line"]
    styles = lines.groupby("feature_id").agg(y=("y", "first"), style=("style", "first"))
    # the outer edges are solid, the two lines between the lanes dashed (drawn from both
    # neighbouring lanes where both paint them)
    assert set(styles.loc[styles["y"].isin([2.0, -10.0]), "style"]) == {"solid"}
    assert set(styles.loc[styles["y"].isin([-2.0, -6.0]), "style"]) == {"dashed"}


def test_map_features_clip_the_ten_kilometre_lanes():
    from tap_bench.sim.roads import road_table

    feats = map_features(road_table("highway"), (100.0, -20.0, 300.0, 10.0))
    xs = np.concatenate([np.array(f[3])[0::2] for f in feats])
    assert xs.min() == 100.0 and xs.max() == 300.0
    assert feats[0][0] == "lane" and feats[0][2] == 4.0


def test_map_table_errors_name_row_and_fix():
    bad = pd.DataFrame({"map_id": ["m"], "feature_id": [0], "kind": ["lanes"], "style": [""],
                        "width": [np.nan], "x": [0.0], "y": [0.0]})
    with pytest.raises(FileFormatError, match="row 0: kind 'lanes'"):
        check_map_table(bad)
    with pytest.raises(FileFormatError, match="missing column"):
        check_map_table(bad.drop(columns="style"))


def _scene() -> pd.DataFrame:
    """Scenario s: the ego drives +x at 10 m/s for 2 s; car 1 is 30 m ahead at 5 m/s and
    missing (invalid) at steps 5-7."""
    t = np.arange(20) / 10
    ego = pd.DataFrame({"scenario_id": "s", "track_id": "ego", "t": t, "x": 10 * t, "y": 0.0,
                        "heading": 0.0, "speed": 10.0, "is_ego": True, "valid": True})
    car = pd.DataFrame({"scenario_id": "s", "track_id": "1", "t": t, "x": 30 + 5 * t,
                        "y": 0.0, "heading": 0.0, "speed": 5.0, "is_ego": False,
                        "valid": ~((t >= 0.45) & (t <= 0.75))})
    return pd.concat([ego, car], ignore_index=True)


def test_episode_documents_quantise_positions_to_a_decimetre():
    scene = _scene()
    episodes = pd.DataFrame({"env": ["e"], "policy": ["p"], "seed": [0], "scenario_id": ["s"],
                             "status": ["ok"], "sdl": ["Straight | Maintain Speed"]})
    eps, entries = episode_index(episodes, has_replay=["s"])
    segments = pd.DataFrame({"scenario_id": ["s", "s"], "track_id": ["ego", "ego"],
                             "axis": ["lateral", "longitudinal"],
                             "label": ["Straight", "Maintain Speed"], "t_start": [0.0, 0.0],
                             "t_end": [2.0, 2.0]})
    (doc,) = episode_chunks(scene, eps, segments)[entries[0]["chunk"]]
    json.dumps(doc, allow_nan=False)  # what the viewer's data file holds
    assert doc["n"] == 20 and doc["tracks"][0]["ego"] and doc["tracks"][0]["id"] == "ego"
    for track, want in zip(doc["tracks"], (scene[scene["track_id"] == "ego"],
                                           scene[scene["track_id"] == "1"]), strict=True):
        xyh = _int16(track["xyh"]).reshape(3, track["n"])
        ok = want["valid"].to_numpy()
        x = xyh[0] * doc["q"] + doc["origin"][0]
        assert np.abs(x[ok] - want["x"].to_numpy()[ok]).max() <= doc["q"] / 2 + 1e-9
        assert (xyh[0][~ok] == MISSING).all() and (xyh[2][~ok] == MISSING).all()
    assert doc["labels"]["ego"]["lateral"] == [[0.0, 2.0, "Straight"]]
    # per-step measures: gap 30 - 5 t - 5 m (one car length), TTC gap / 5 m/s, capped 10 s
    m = doc["measures"]
    gap = _int16(m["gap"]) / 100
    t = np.arange(m["n"]) / 10
    valid = ~((t >= 0.45) & (t <= 0.75))
    assert np.allclose(gap[valid], (25 - 5 * t)[valid], atol=0.006)
    assert (_int16(m["gap"])[~valid] == MISSING).all()  # no leader while it is missing
    assert np.allclose(_int16(m["ttc"])[valid] / 100, np.minimum((25 - 5 * t) / 5, 10)[valid],
                       atol=0.006)
    assert m["scored_from"] is None  # a 2 s episode lies wholly in the 2 s burn-in


def test_episode_index_marks_novel_labels_per_env_and_policy():
    episodes = pd.DataFrame({"env": ["a", "a", "b"], "policy": ["p", "q", "p"], "seed": [0, 0, 0],
                             "scenario_id": ["a/p/s0", "a/q/s0", "b/p/s0"],
                             "status": ["ok", "ok", "ok"], "sdl": ["X | Y", "X | Y", "X | Y"],
                             "crashed": [True, False, pd.NA]})
    novel = pd.DataFrame({"env": ["a", "all"], "policy": ["p", "p"], "label": ["X | Y", "X | Y"],
                          "reference": ["WOMD", "WOMD"]})
    eps, entries = episode_index(episodes, novel_labels=novel)
    assert [e["novel"] for e in entries] == [["WOMD"], [], []]
    assert [e["crashed"] for e in entries] == [True, False, False]
    assert list(eps["chunk"]) == ["a-0", "a-0", "b-0"]  # every policy of a seed together


def test_encode_int16_is_little_endian():
    assert _int16(encode_int16(np.array([1, -2, MISSING]))).tolist() == [1, -2, MISSING]


def test_womd_maps_belong_to_the_scenarios_read(womd_dir):
    from tap_bench.sources import read_womd
    from tap_bench.sources.maps import read_maps

    for name in ("motion_data_one_scenario.tfrecord", "motion_data_one_example.tfrecord",
                 "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl"):
        maps = check_map_table(read_maps(womd_dir / name), name)
        sids = set(read_womd(womd_dir / name)["scenario_id"].astype(str))
        assert set(maps["map_id"]) == sids, name
        assert {"lane", "road_line", "road_edge"} <= set(maps["kind"]), name


def test_signal_field_gives_each_stop_point_its_state_per_step():
    from tap_bench.bench.report.viewer.data import signal_field
    from tap_bench.womd.roadmap import LANE_STATES, SignalStates

    states = np.arange(len(LANE_STATES), dtype=np.int8)  # every state number, one a step
    signals = SignalStates(np.array([11, 12]), np.c_[states, states[::-1]],
                           np.array([[1.234, -5.0], [7.0, 8.0]]))
    field = signal_field(signals)
    assert field["lanes"] == [11, 12] and field["points"] == [[1.23, -5.0], [7.0, 8.0]]
    want = {"unknown": "u", "arrow_stop": "r", "arrow_caution": "y", "arrow_go": "g",
            "stop": "r", "caution": "y", "go": "g", "flashing_stop": "r",
            "flashing_caution": "y"}
    assert [s[0] for s in field["states"]] == [want[n] for n in LANE_STATES]
    assert [s[1] for s in field["states"]] == [want[n] for n in LANE_STATES[::-1]]
    assert signal_field(SignalStates.empty(91)) is None


def test_the_womd_viewer_carries_each_scenes_signals(womd_dir, tmp_path, monkeypatch):
    from tap_bench.bench.report.viewer import build
    from tap_bench.sources.maps import read_road_maps

    files = [womd_dir / "motion_data_one_scenario.tfrecord",
             womd_dir / "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl"]
    captured = {}
    monkeypatch.setattr(build, "write_viewer",
                        lambda output, index, chunks: captured.update(chunks) or output)
    build.write_womd_viewer(files, tmp_path / "v")
    docs = {d["id"]: d for docs in captured.values() for d in docs}
    roads = read_road_maps(files)
    assert set(docs) == set(roads)
    for sid, doc in docs.items():
        signals = roads[sid].signals
        field = doc["signals"]
        assert len(field["states"]) == signals.state.shape[0]  # one a record step
        assert field["lanes"] == signals.lane.tolist()
        assert np.allclose(field["points"], signals.stop_point, atol=0.01)
        letters = np.array([list(s) for s in field["states"]])
        assert ((letters == "r") == np.isin(signals.state, [1, 4, 7])).all()
        assert ((letters == "y") == np.isin(signals.state, [2, 5, 8])).all()
        assert ((letters == "g") == np.isin(signals.state, [3, 6])).all()
    assert (np.array([list(s) for s in docs["637f20cafde22ff8"]["signals"]["states"]])
            == "r").any()
