"""WOMD's ``tf.Example`` motion format to the trajectory table.

Each record is a ``tf.Example`` with fixed-size agent slots (128 in WOMD) and, per slot,
``state/past/*`` (10 steps), ``state/current/*`` (1) and ``state/future/*`` (80) features,
agent-major. Past, current and future are put back in time order (91 steps); padding slots
(``state/id`` = -1) are dropped. ``t`` is ``timestamp_micros`` / 1e6, taken per step from
the valid states (all valid states of a step share it). ``heading`` is ``bbox_yaw``;
``vx``, ``vy`` are ``velocity_x``, ``velocity_y`` and ``speed`` is ``hypot(vx, vy)``, as for
``Scenario`` records. The message classes are built at run time, like the Scenario ones.
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.message import DecodeError

from tap_bench.errors import WomdRecordError
from tap_bench.womd.scenario import BOX_SIZE_FIX, bad_box_size, trajectory_table
from tap_bench.womd.tfrecord import Record

__all__ = ["Example", "decode_tf_example", "is_motion_example"]

_F = descriptor_pb2.FieldDescriptorProto


def _example_class() -> type:
    fd = descriptor_pb2.FileDescriptorProto(name="tensorflow/core/example/example.proto",
                                            package="tensorflow", syntax="proto3")
    for name, number_type in (("BytesList", _F.TYPE_BYTES), ("FloatList", _F.TYPE_FLOAT),
                              ("Int64List", _F.TYPE_INT64)):
        msg = fd.message_type.add(name=name)
        field = msg.field.add(name="value", number=1, type=number_type,
                              label=_F.LABEL_REPEATED)
        if number_type != _F.TYPE_BYTES:
            field.options.packed = True
    feature = fd.message_type.add(name="Feature")
    feature.oneof_decl.add(name="kind")
    for number, (name, type_name) in enumerate((("bytes_list", "BytesList"),
                                                ("float_list", "FloatList"),
                                                ("int64_list", "Int64List")), start=1):
        feature.field.add(name=name, number=number, type=_F.TYPE_MESSAGE,
                          label=_F.LABEL_OPTIONAL, type_name=f".tensorflow.{type_name}",
                          oneof_index=0)
    features = fd.message_type.add(name="Features")
    entry = features.nested_type.add(name="FeatureEntry")
    entry.options.map_entry = True
    entry.field.add(name="key", number=1, type=_F.TYPE_STRING, label=_F.LABEL_OPTIONAL)
    entry.field.add(name="value", number=2, type=_F.TYPE_MESSAGE, label=_F.LABEL_OPTIONAL,
                    type_name=".tensorflow.Feature")
    features.field.add(name="feature", number=1, type=_F.TYPE_MESSAGE,
                       label=_F.LABEL_REPEATED, type_name=".tensorflow.Features.FeatureEntry")
    example = fd.message_type.add(name="Example")
    example.field.add(name="features", number=1, type=_F.TYPE_MESSAGE,
                      label=_F.LABEL_OPTIONAL, type_name=".tensorflow.Features")
    pool = descriptor_pool.DescriptorPool()
    pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName("tensorflow.Example"))


Example = _example_class()
"""TensorFlow's ``tf.train.Example`` message class, built at run time."""

_PARTS = ("past", "current", "future")
_TYPES = {1: "vehicle", 2: "pedestrian", 3: "cyclist"}
_NO_ID = ("Every scenario needs its id: without one it would be merged with other "
          "scenarios. `tap-bench ingest --on-error skip` (on_error='skip') keeps the file's "
          "other records; a rollout reads whole files: leave this one out.")
_FIX = ("Is the file a WOMD tf_example file? A file of Scenario records "
        "(uncompressed/scenario/...) is read with format='scenario'.")


def _values(features, key: str, record: Record, dtype=np.float64) -> np.ndarray:
    if key not in features:
        raise record.error(f"the tf.Example has no feature {key!r}", _FIX)
    feature = features[key]
    kind = feature.WhichOneof("kind")
    values = getattr(feature, kind).value if kind else []
    return np.array(values, dtype=dtype)


def is_motion_example(data: bytes) -> bool:
    """Whether a record is a WOMD motion ``tf.Example`` (it has ``state/id``)."""
    try:
        example = Example.FromString(data)
    except DecodeError:
        return False
    return "state/id" in example.features.feature


def decode_tf_example(record: Record, *, object_types: frozenset[str] | None = None,
                      source: str = "womd") -> pa.Table:
    """Decode one motion ``tf.Example`` record into a trajectory table.

    Args:
        record: the record (its path, index and offset name it in errors).
        object_types: keep only agents of these types (None keeps all).
        source: the value of the ``source`` column.

    Returns:
        A table with the columns of :data:`tap_bench.womd.scenario.SCENARIO_COLUMNS`, one
        row per agent per step (agents in slot order, steps in time order).

    Raises:
        WomdRecordError: the record is not a motion tf.Example, its features disagree in
            size, or a feature holds the wrong kind of values (text that is not UTF-8, an
            empty id, numbers where bytes belong).
    """
    try:
        features = Example.FromString(record.data).features.feature
    except DecodeError as err:
        raise record.error(f"not a serialized tf.Example (protobuf: {err})", _FIX) from None
    try:
        return _decode_features(features, record, object_types, source)
    except WomdRecordError:
        raise
    except (AttributeError, IndexError, ValueError, TypeError) as err:  # + UnicodeDecodeError
        raise record.error(f"a feature of the tf.Example has the wrong size or kind "
                           f"({type(err).__name__}: {err})", _FIX) from None


def _decode_features(features, record: Record, object_types: frozenset[str] | None,
                     source: str) -> pa.Table:
    """:func:`decode_tf_example` of the parsed features."""
    ids = _values(features, "state/id", record)
    n_slots = len(ids)
    if n_slots == 0:
        raise record.error("the tf.Example has no agent slots (state/id is empty)", _FIX)

    def series(name: str, dtype=np.float64) -> np.ndarray:
        parts = [_values(features, f"state/{part}/{name}", record, dtype) for part in _PARTS]
        for part, values in zip(_PARTS, parts, strict=True):
            if len(values) % n_slots:
                raise record.error(f"state/{part}/{name} has {len(values)} values, not a "
                                   f"multiple of the {n_slots} agent slots", _FIX)
        return np.concatenate([v.reshape(n_slots, -1) for v in parts], axis=1)

    valid = series("valid", np.int64) != 0
    micros = series("timestamp_micros", np.int64)
    n_steps = valid.shape[1]
    # One time per step, from the valid states (all share it); steps nobody is valid at
    # are filled in 0.1 s from their neighbour.
    masked = np.where(valid, micros, np.iinfo(np.int64).min)
    step_micros = masked.max(axis=0).astype(np.float64)
    missing = ~valid.any(axis=0)
    if missing.all():
        raise record.error("no agent has a valid state at any step", "Skip the record.")
    known = np.flatnonzero(~missing)
    steps = np.arange(n_steps)
    step_micros[missing] = np.interp(steps[missing], known, step_micros[known],
                                     left=np.nan, right=np.nan)
    if np.isnan(step_micros).any():
        first, last = known[0], known[-1]
        step_micros[:first] = step_micros[first] - (first - steps[:first]) * 1e5
        step_micros[last + 1:] = step_micros[last] + (steps[last + 1:] - last) * 1e5
    times = step_micros / 1e6

    slot_type = _values(features, "state/type", record)
    keep = ids != -1
    names = np.array([_TYPES.get(int(v), "other") for v in slot_type], dtype=object)
    if object_types is not None:
        keep &= np.isin(names, list(object_types))
    kept = np.flatnonzero(keep)

    def grid(name: str) -> np.ndarray:
        return series(name)[kept].ravel()

    flags = {}
    for key in ("is_sdc", "objects_of_interest", "tracks_to_predict"):
        flags[key] = (_values(features, f"state/{key}", record, np.int64)[kept] > 0
                      if f"state/{key}" in features else np.zeros(len(kept), dtype=bool))
    scenario_id = (_values(features, "scenario/id", record, object)[0].decode()
                   if "scenario/id" in features else f"{record.path}#{record.index}")
    if not scenario_id:
        raise record.error("the tf.Example's scenario/id is empty", _NO_ID)
    difficulty = (_values(features, "state/difficulty_level", record, np.int64)[kept]
                  if "state/difficulty_level" in features else np.zeros(len(kept)))
    states = {name: grid(key) for name, key in (
        ("x", "x"), ("y", "y"), ("z", "z"), ("heading", "bbox_yaw"), ("vx", "velocity_x"),
        ("vy", "velocity_y"), ("length", "length"), ("width", "width"), ("height", "height"))}
    states["valid"] = valid[kept].ravel()
    track_ids = [str(int(i)) for i in ids[kept]]
    problem = bad_box_size(track_ids, len(times), states)
    if problem is not None:
        raise record.error(problem, BOX_SIZE_FIX)
    return trajectory_table(
        scenario_id, times, [str(int(i)) for i in ids[kept]], list(names[kept]), states,
        is_ego=flags["is_sdc"], object_of_interest=flags["objects_of_interest"],
        track_to_predict=flags["tracks_to_predict"],
        prediction_difficulty=np.where(flags["tracks_to_predict"], difficulty, 0),
        source=source)
