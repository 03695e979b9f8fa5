"""The maps of driving-data files as a map table (:mod:`tap_bench.maps`), one ``map_id`` per
scenario, for the viewer and reports; and as :class:`~tap_bench.womd.roadmap.RoadMap`
objects (lanes with their topology, signals, stop signs) for closed-loop simulation
(:func:`read_road_maps`).

The built-in readers (:mod:`tap_bench.sources.builtin`) carry the map differently; files of
other registered formats give no map:

- ``Scenario`` records: ``map_features`` (map.proto), read with
  :data:`tap_bench.womd.proto.ScenarioMapView`;
- motion ``tf.Example`` records: ``roadgraph_samples/*`` points (about 0.5 m apart), grouped
  into polylines by their ``id``;
- ScenarioNet pickles: ``map_features``, a dict of ``{"type", "polyline" or "polygon"}``.

Lanes (centre lines; WOMD gives no width), painted lines (broken ones ``dashed``), road
edges and crosswalks are kept; stop signs, speed bumps and driveways are not drawn.
"""

from __future__ import annotations

import os
from collections.abc import Container, Generator, Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from google.protobuf.message import DecodeError

from tap_bench.errors import FileFormatError, WomdRecordError
from tap_bench.maps import MAP_COLUMNS, empty_map
from tap_bench.sources.ingest import _file_format, record_files
from tap_bench.sources.scenarionet import load_scenarionet
from tap_bench.womd import proto
from tap_bench.womd.roadmap import (
    RoadMap,
    scenario_road_map,
    scenarionet_road_map,
    tf_example_road_map,
)
from tap_bench.womd.tf_example import Example
from tap_bench.womd.tfrecord import iter_records, read_record

__all__ = ["iter_maps", "iter_road_maps", "read_maps", "read_road_maps", "read_scene_maps"]

_BROKEN_LINES = {1, 4, 5}  # RoadLineType: BROKEN_SINGLE_WHITE, BROKEN_SINGLE/DOUBLE_YELLOW
# tf.Example roadgraph_samples/type -> (kind, style)
_ROADGRAPH = {1: ("lane", ""), 2: ("lane", ""), 3: ("lane", ""),
              **{k: ("road_line", "dashed" if k in (6, 9, 10) else "solid") for k in range(6, 14)},
              15: ("road_edge", ""), 16: ("road_edge", ""), 18: ("crosswalk", "")}


class _Features:
    """Collects features as map-table columns."""

    def __init__(self, keep: Container[str] | None = None) -> None:
        self.cols: dict[str, list] = {c: [] for c in MAP_COLUMNS}
        self.next_id = 0
        self.keep = keep

    def add(self, map_id: str, kind: str, style: str, xy: np.ndarray) -> None:
        if self.keep is not None and map_id not in self.keep:
            return
        xy = np.asarray(xy, dtype=float).reshape(-1, xy.shape[-1] if xy.ndim > 1 else 2)[:, :2]
        xy = xy[np.isfinite(xy).all(axis=1)]
        if kind == "crosswalk" and len(xy) >= 3:
            xy = np.vstack([xy, xy[:1]])  # a polygon drawn as a closed polyline
        if len(xy) < 2:
            return
        n = len(xy)
        self.cols["map_id"] += [map_id] * n
        self.cols["feature_id"] += [self.next_id] * n
        self.cols["kind"] += [kind] * n
        self.cols["style"] += [style] * n
        self.cols["width"] += [np.nan] * n
        self.cols["x"] += xy[:, 0].tolist()
        self.cols["y"] += xy[:, 1].tolist()
        self.next_id += 1

    def table(self) -> pd.DataFrame:
        if not self.cols["x"]:
            return empty_map()
        out = pd.DataFrame(self.cols)
        out["feature_id"] = out["feature_id"].astype(np.int64)
        return out

    def take(self) -> pd.DataFrame | None:
        """The rows collected since the last take (None: none), then forgotten (feature
        ids go on counting)."""
        if not self.cols["x"]:
            return None
        out = self.table()
        self.cols = {c: [] for c in MAP_COLUMNS}
        return out


def _points(points) -> np.ndarray:
    return np.array([(p.x, p.y) for p in points], dtype=float).reshape(-1, 2)


def _scenario_maps(path: Path, out: _Features, records: Iterable[Any] | None = None
                   ) -> Generator[None, None, None]:
    for record in iter_records(path) if records is None else records:
        try:
            view = proto.ScenarioMapView.FromString(record.data)
        except DecodeError as err:
            raise record.error(f"not a serialized WOMD Scenario proto (protobuf: {err})",
                               "Is the file a WOMD scenario file?") from None
        for feature in view.map_features:
            if feature.HasField("lane"):
                out.add(view.scenario_id, "lane", "", _points(feature.lane.polyline))
            elif feature.HasField("road_line"):
                style = "dashed" if feature.road_line.type in _BROKEN_LINES else "solid"
                out.add(view.scenario_id, "road_line", style,
                        _points(feature.road_line.polyline))
            elif feature.HasField("road_edge"):
                out.add(view.scenario_id, "road_edge", "", _points(feature.road_edge.polyline))
            elif feature.HasField("crosswalk"):
                out.add(view.scenario_id, "crosswalk", "", _points(feature.crosswalk.polygon))
        yield


def _tf_example_maps(path: Path, out: _Features, records: Iterable[Any] | None = None
                     ) -> Generator[None, None, None]:
    for record in iter_records(path) if records is None else records:
        features = Example.FromString(record.data).features.feature
        if "roadgraph_samples/xyz" not in features:
            yield
            continue
        sid = (features["scenario/id"].bytes_list.value[0].decode()
               if "scenario/id" in features else f"{record.path}#{record.index}")
        xyz = np.array(features["roadgraph_samples/xyz"].float_list.value).reshape(-1, 3)
        kind = np.array(features["roadgraph_samples/type"].int64_list.value)
        ids = np.array(features["roadgraph_samples/id"].int64_list.value)
        valid = np.array(features["roadgraph_samples/valid"].int64_list.value) > 0
        if not (len(xyz) == len(kind) == len(ids) == len(valid)):
            raise WomdRecordError(str(path), record.index, record.offset,
                                  "roadgraph_samples/* features differ in length",
                                  "The file may be damaged; view it without its map.")
        xyz, kind, ids = xyz[valid], kind[valid], ids[valid]
        # consecutive samples of one id (and type) form one polyline
        cut = np.flatnonzero((ids[1:] != ids[:-1]) | (kind[1:] != kind[:-1])) + 1
        for part in np.split(np.arange(len(ids)), cut):
            if len(part) and int(kind[part[0]]) in _ROADGRAPH:
                k, style = _ROADGRAPH[int(kind[part[0]])]
                out.add(sid, k, style, xyz[part, :2])
        yield


def _scenarionet_maps(path: Path, out: _Features, records: Iterable[Any] | None = None
                      ) -> Generator[None, None, None]:

    scenario = load_scenarionet(path)
    meta = scenario.get("metadata", {}) if isinstance(scenario, dict) else {}
    sid = str(meta.get("scenario_id", scenario.get("id", path.stem)))
    for feature in (scenario.get("map_features") or {}).values():
        kind = str(feature.get("type", ""))
        if kind.startswith("LANE"):
            out.add(sid, "lane", "", np.asarray(feature.get("polyline", [])))
        elif kind.startswith("ROAD_LINE"):
            style = "dashed" if "BROKEN" in kind else "solid"
            out.add(sid, "road_line", style, np.asarray(feature.get("polyline", [])))
        elif kind.startswith("ROAD_EDGE"):
            out.add(sid, "road_edge", "", np.asarray(feature.get("polyline", [])))
        elif kind == "CROSSWALK":
            out.add(sid, "crosswalk", "", np.asarray(feature.get("polygon", [])))
    yield


_MAP_READERS = {"scenario": _scenario_maps, "tf_example": _tf_example_maps,
                "scenarionet": _scenarionet_maps}
"""Reader name (:mod:`tap_bench.sources.registry`) -> how its files carry the map."""


def read_maps(paths: str | os.PathLike | Iterable[str | os.PathLike], *,
              scenario_ids: Container[str] | None = None) -> pd.DataFrame:
    """The map features of every scenario in driving-data files, as one map table.

    Args:
        paths: files, directories or glob patterns, as for :func:`tap_bench.sources.read_womd`.
        scenario_ids: keep only the maps of these scenarios (the others are read, one
            record at a time, and dropped); None keeps all.

    Returns:
        the map table (``map_id`` is the scenario id); no rows for files without a map.

    Raises:
        WomdRecordError: a record that cannot be read, naming file, record and offset.
    """

    out = _Features(scenario_ids)
    for path in record_files(paths):  # folders and globs: WOMD files only, as ingest
        read = _MAP_READERS.get(_file_format(path, "auto", True).name)
        if read is not None:
            for _ in read(path, out):
                pass
    return out.table()


def iter_maps(paths: str | os.PathLike | Iterable[str | os.PathLike]
              ) -> Iterator[pd.DataFrame]:
    """The map table of each scenario of driving-data files with a map, one at a time in
    file and record order: together, the rows (and feature ids) :func:`read_maps` gives,
    with one record's map in memory at a time.

    Raises:
        WomdRecordError: a record that cannot be read, naming file, record and offset.
    """
    out = _Features()
    for path in record_files(paths):
        read = _MAP_READERS.get(_file_format(path, "auto", True).name)
        if read is None:
            continue
        for _ in read(path, out):
            table = out.take()
            if table is not None:
                yield table


def read_scene_maps(scenes: Iterable[Any]) -> pd.DataFrame:
    """The map table of some scenes, each read alone: a record at its byte offset (where
    known), not by reading its file from the start.

    Args:
        scenes: where each scene is (:class:`tap_bench.sim.womd_scene.SceneRef`: ``path``,
            ``record``, ``format``, ``offset``), in the order their rows go.

    Returns:
        the rows :func:`read_maps` gives for these scenes when they are in file order.

    Raises:
        WomdRecordError: a record that cannot be read, naming file, record and offset.
    """
    out = _Features()
    for scene in scenes:
        read = _MAP_READERS.get(scene.format)
        if read is None:
            continue
        records = None
        if scene.format != "scenarionet":
            records = ([read_record(scene.path, scene.record, scene.offset)]
                if scene.offset >= 0 else (r for r in iter_records(scene.path)
                                           if r.index == scene.record))
        for _ in read(Path(scene.path), out, records):
            pass
    return out.table()


# ------------------------------------------------------------------ road maps (closed loop)


def iter_road_maps(paths: str | os.PathLike | Iterable[str | os.PathLike]
                   ) -> Iterator[RoadMap]:
    """The road map of every scenario in driving-data files, in file and record order.

    Args:
        paths: files, directories or glob patterns (:func:`tap_bench.sources.read_womd`).

    Raises:
        WomdRecordError / FileFormatError: a record or file that cannot be read, named.
    """
    for path in record_files(paths):  # folders and globs: WOMD files only, as ingest
        name = _file_format(path, "auto", True).name
        if name == "scenarionet":
            yield scenarionet_road_map(load_scenarionet(path), source=str(path))
        elif name in ("scenario", "tf_example"):
            for record in iter_records(path):
                where = f"{path} record {record.index}"
                try:
                    road = (scenario_road_map(record.data, source=where) if name == "scenario"
                            else tf_example_road_map(record.data, source=where))
                except FileFormatError as err:
                    raise WomdRecordError(str(path), record.index, record.offset, str(err),
                                          "Is the file a WOMD scenario file?") from None
                if road is not None:
                    yield road


def read_road_maps(paths: str | os.PathLike | Iterable[str | os.PathLike]
                   ) -> dict[str, RoadMap]:
    """:func:`iter_road_maps` as a dict scenario id -> :class:`~tap_bench.womd.roadmap.RoadMap`."""
    return {road.scenario_id: road for road in iter_road_maps(paths)}
