"""WOMD's ``Scenario`` messages, built at run time from a descriptor written here.

No protoc step, no generated code, no TensorFlow: the message classes come from a
``FileDescriptorProto`` assembled from the field tables below (field numbers from Waymo's
``scenario.proto``, proto2, package ``waymo.open_dataset``), which the ``protobuf`` package
turns into classes at import.

Two files are built:

- ``waymo.open_dataset`` (:data:`Scenario`, :data:`Track`, :data:`ObjectState`,
  :data:`RequiredPrediction`): the messages as WOMD defines them, used to write scenarios and
  to decode them field by field. ``DynamicMapState`` and ``MapFeature`` are declared without
  fields: their content is kept as unknown fields, so a parsed scenario re-serialises with
  its map intact. ``Track`` also declares two tap-bench fields (51001, 51002) that keep a
  table's string track ids and extra columns; other WOMD tools keep them as unknown fields.
- ``tap_bench.womd.view`` (:data:`ScenarioView`): the same wire format read lazily. A
  track's states stay raw bytes, decoded in bulk with numpy (:mod:`tap_bench.womd.scenario`),
  and enums are plain ints so an unknown object type is seen rather than dropped.
"""

from __future__ import annotations

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

__all__ = [
    "OBJECT_STATE_FIELDS",
    "OBJECT_TYPE_NAMES",
    "TAP_BENCH_COLUMNS_FIELD",
    "TAP_BENCH_TRACK_ID_FIELD",
    "MapPointView",
    "ObjectState",
    "RequiredPrediction",
    "Scenario",
    "ScenarioMapPointsView",
    "ScenarioMapView",
    "ScenarioView",
    "Track",
]

_F = descriptor_pb2.FieldDescriptorProto
_SCALARS = {
    "double": _F.TYPE_DOUBLE, "float": _F.TYPE_FLOAT, "int32": _F.TYPE_INT32,
    "int64": _F.TYPE_INT64,
    "bool": _F.TYPE_BOOL, "string": _F.TYPE_STRING, "bytes": _F.TYPE_BYTES,
}

OBJECT_STATE_FIELDS = (
    ("center_x", 2, "double"),
    ("center_y", 3, "double"),
    ("center_z", 4, "double"),
    ("length", 5, "float"),
    ("width", 6, "float"),
    ("height", 7, "float"),
    ("heading", 8, "float"),
    ("velocity_x", 9, "float"),
    ("velocity_y", 10, "float"),
    ("valid", 11, "bool"),
)
"""ObjectState fields: (name, number, type). Positions [m], heading [rad], velocity [m/s]."""

OBJECT_TYPE_NAMES = {0: "other", 1: "vehicle", 2: "pedestrian", 3: "cyclist", 4: "other"}
"""Track.ObjectType (UNSET 0, VEHICLE 1, PEDESTRIAN 2, CYCLIST 3, OTHER 4) to the contract's
object_type; UNSET is read as ``other``."""

TAP_BENCH_TRACK_ID_FIELD = 51001
"""Track field (string) holding a table's track_id when it is not a WOMD int32 id."""
TAP_BENCH_COLUMNS_FIELD = 51002
"""Track field (string, JSON) holding a table's columns that WOMD has no field for."""

_TRACK_EXTRA = (
    ("tap_bench_track_id", TAP_BENCH_TRACK_ID_FIELD, "string"),
    ("tap_bench_columns", TAP_BENCH_COLUMNS_FIELD, "string"),
)

# name -> fields (name, number, type); "repeated X" marks repeated fields, ".Name" a message,
# "enum:.Name" an enum.
_WAYMO = {
    "ObjectState": OBJECT_STATE_FIELDS,
    "Track": (("id", 1, "int32"), ("object_type", 2, "enum:.Track.ObjectType"),
              ("states", 3, "repeated .ObjectState"), *_TRACK_EXTRA),
    "DynamicMapState": (),
    "MapFeature": (),
    "RequiredPrediction": (("track_index", 1, "int32"),
                           ("difficulty", 2, "enum:.RequiredPrediction.DifficultyLevel")),
    "Scenario": (("timestamps_seconds", 1, "repeated double"),
                 ("tracks", 2, "repeated .Track"),
                 ("objects_of_interest", 4, "repeated int32"),
                 ("scenario_id", 5, "string"),
                 ("sdc_track_index", 6, "int32"),
                 ("dynamic_map_states", 7, "repeated .DynamicMapState"),
                 ("map_features", 8, "repeated .MapFeature"),
                 ("current_time_index", 10, "int32"),
                 ("tracks_to_predict", 11, "repeated .RequiredPrediction")),
}
_WAYMO_ENUMS = {
    "Track": ("ObjectType", ("TYPE_UNSET", "TYPE_VEHICLE", "TYPE_PEDESTRIAN", "TYPE_CYCLIST",
                             "TYPE_OTHER")),
    "RequiredPrediction": ("DifficultyLevel", ("NONE", "LEVEL_1", "LEVEL_2")),
}
_VIEW = {
    "TrackView": (("id", 1, "int32"), ("object_type", 2, "int32"),
                  ("states", 3, "repeated bytes"), *_TRACK_EXTRA),
    "RequiredPredictionView": (("track_index", 1, "int32"), ("difficulty", 2, "int32")),
    "ScenarioView": (("timestamps_seconds", 1, "repeated double"),
                     ("tracks", 2, "repeated .TrackView"),
                     ("objects_of_interest", 4, "repeated int32"),
                     ("scenario_id", 5, "string"),
                     ("sdc_track_index", 6, "int32"),
                     ("current_time_index", 10, "int32"),
                     ("tracks_to_predict", 11, "repeated .RequiredPredictionView")),
    # the map (map.proto): polylines of lanes, painted lines, road edges; crosswalk polygons
    "MapPointView": (("x", 1, "double"), ("y", 2, "double"), ("z", 3, "double")),
    # topology (map.proto): entry/exit lanes, neighbours with index ranges, boundaries
    "BoundarySegmentView": (("lane_start_index", 1, "int32"), ("lane_end_index", 2, "int32"),
                            ("boundary_feature_id", 3, "int64"),
                            ("boundary_type", 4, "int32")),
    "LaneNeighborView": (("feature_id", 1, "int64"), ("self_start_index", 2, "int32"),
                         ("self_end_index", 3, "int32"), ("neighbor_start_index", 4, "int32"),
                         ("neighbor_end_index", 5, "int32")),
    "LaneCenterView": (("speed_limit_mph", 1, "double"), ("type", 2, "int32"),
                       ("interpolating", 3, "bool"),
                       ("polyline", 8, "repeated .MapPointView"),
                       ("entry_lanes", 9, "repeated int64"),
                       ("exit_lanes", 10, "repeated int64"),
                       ("left_neighbors", 11, "repeated .LaneNeighborView"),
                       ("right_neighbors", 12, "repeated .LaneNeighborView"),
                       ("left_boundaries", 13, "repeated .BoundarySegmentView"),
                       ("right_boundaries", 14, "repeated .BoundarySegmentView")),
    "LineView": (("type", 1, "int32"), ("polyline", 2, "repeated .MapPointView")),
    "PolygonView": (("polygon", 1, "repeated .MapPointView"),),
    "StopSignView": (("lane", 1, "repeated int64"), ("position", 2, ".MapPointView")),
    "MapFeatureView": (("id", 1, "int64"), ("lane", 3, ".LaneCenterView"),
                       ("road_line", 4, ".LineView"), ("road_edge", 5, ".LineView"),
                       ("stop_sign", 7, ".StopSignView"),
                       ("crosswalk", 8, ".PolygonView")),
    # traffic signals per step (Scenario.dynamic_map_states, one per timestamp)
    "TrafficSignalLaneStateView": (("lane", 1, "int64"), ("state", 2, "int32"),
                                   ("stop_point", 3, ".MapPointView")),
    "DynamicMapStateView": (("lane_states", 1, "repeated .TrafficSignalLaneStateView"),),
    "ScenarioMapView": (("timestamps_seconds", 1, "repeated double"),
                        ("scenario_id", 5, "string"),
                        ("dynamic_map_states", 7, "repeated .DynamicMapStateView"),
                        ("map_features", 8, "repeated .MapFeatureView")),
}


_POINT_LISTS = ("LaneCenterView", "LineView", "PolygonView", "MapFeatureView",
                "ScenarioMapView")


def _points_as_bytes(messages: dict) -> dict:
    """The map's messages again under names ending ``PointsView``, with every list of
    points (``repeated .MapPointView``) read as ``repeated bytes``: one serialized
    ``MapPoint`` per item, decoded in bulk (:func:`tap_bench.womd.roadmap.map_points`)."""
    renamed = {f".{name}": f".{name.removesuffix('View')}PointsView" for name in _POINT_LISTS}
    out = {}
    for name in _POINT_LISTS:
        fields = []
        for field_name, number, kind in messages[name]:
            prefix, _, target = kind.rpartition(" ")
            if target == ".MapPointView" and prefix == "repeated":
                kind = "repeated bytes"
            elif target in renamed:
                kind = f"{prefix} {renamed[target]}".lstrip()
            fields.append((field_name, number, kind))
        out[renamed[f".{name}"][1:]] = tuple(fields)
    return out


_VIEW.update(_points_as_bytes(_VIEW))


def _file(name: str, package: str, messages: dict,
          enums: dict) -> descriptor_pb2.FileDescriptorProto:
    fd = descriptor_pb2.FileDescriptorProto(name=name, package=package, syntax="proto2")
    for msg_name, fields in messages.items():
        msg = fd.message_type.add(name=msg_name)
        if msg_name in enums:
            enum_name, values = enums[msg_name]
            enum = msg.enum_type.add(name=enum_name)
            for number, value in enumerate(values):
                enum.value.add(name=value, number=number)
        for field_name, number, kind in fields:
            field = msg.field.add(name=field_name, number=number, label=_F.LABEL_OPTIONAL)
            if kind.startswith("repeated "):
                field.label = _F.LABEL_REPEATED
                kind = kind.removeprefix("repeated ")
            if kind.startswith("enum:"):
                field.type = _F.TYPE_ENUM
                field.type_name = f".{package}{kind.removeprefix('enum:')}"
            elif kind.startswith("."):
                field.type = _F.TYPE_MESSAGE
                field.type_name = f".{package}{kind}"
            else:
                field.type = _SCALARS[kind]
    return fd


_POOL = descriptor_pool.DescriptorPool()
_POOL.Add(_file("waymo_open_dataset/protos/scenario.proto", "waymo.open_dataset", _WAYMO,
                _WAYMO_ENUMS))
_POOL.Add(_file("tap_bench/womd/view.proto", "tap_bench.womd.view", _VIEW, {}))


def _cls(full_name: str) -> type:
    return message_factory.GetMessageClass(_POOL.FindMessageTypeByName(full_name))


Scenario = _cls("waymo.open_dataset.Scenario")
"""WOMD ``Scenario`` message class."""
Track = _cls("waymo.open_dataset.Track")
"""WOMD ``Track`` message class."""
ObjectState = _cls("waymo.open_dataset.ObjectState")
"""WOMD ``ObjectState`` message class (one state of one track at one time step)."""
RequiredPrediction = _cls("waymo.open_dataset.RequiredPrediction")
"""WOMD ``RequiredPrediction`` message class (a track to predict and its difficulty)."""
ScenarioView = _cls("tap_bench.womd.view.ScenarioView")
"""A Scenario read lazily: track states stay raw bytes and enums plain ints."""
ScenarioMapView = _cls("tap_bench.womd.view.ScenarioMapView")
"""A Scenario's id, timestamps, map features (lanes with their topology, road lines, road
edges, stop signs, crosswalks; WOMD's map.proto field numbers) and traffic-signal states per
step; the tracks are skipped."""
ScenarioMapPointsView = _cls("tap_bench.womd.view.ScenarioMapPointsView")
""":data:`ScenarioMapView` with every list of points (lane centre lines, lines, edges,
crosswalk polygons) kept as one serialized ``MapPoint`` per item, for decoding in bulk."""
MapPointView = _cls("tap_bench.womd.view.MapPointView")
"""One map point (map.proto's ``MapPoint``): x, y, z [m]."""
