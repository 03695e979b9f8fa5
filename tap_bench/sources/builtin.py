"""The built-in readers: WOMD ``Scenario`` and ``tf.Example`` TFRecords, ScenarioNet pickles
(WOMD, nuPlan, Argoverse 2 ... converted by ScenarioNet)."""

from __future__ import annotations

import os

import pyarrow as pa

from tap_bench.sources.registry import Reader, register_reader
from tap_bench.sources.scenarionet import decode_scenarionet, load_scenarionet
from tap_bench.womd.scenario import decode_scenario
from tap_bench.womd.tf_example import decode_tf_example, is_motion_example

__all__ = ["SCENARIO", "SCENARIONET", "TF_EXAMPLE"]


def read_scenarionet_file(path: str | os.PathLike, object_types: frozenset[str] | None
                          ) -> pa.Table:
    """A ScenarioNet pickle (restricted unpickler) to the trajectory table."""
    return decode_scenarionet(load_scenarionet(path), path=str(path), object_types=object_types)


def _decode_scenario(record, object_types: frozenset[str] | None) -> pa.Table:
    return decode_scenario(record, object_types=object_types)


def _decode_tf_example(record, object_types: frozenset[str] | None) -> pa.Table:
    return decode_tf_example(record, object_types=object_types)


TF_EXAMPLE = register_reader(Reader(
    "tf_example", "tfrecord", _decode_tf_example, sniff=is_motion_example,
    description="WOMD motion tf.Example TFRecords (uncompressed/tf_example/...)"))
SCENARIO = register_reader(Reader(
    "scenario", "tfrecord", _decode_scenario, sniff=None,
    description="WOMD Scenario protos in TFRecords (uncompressed/scenario/...); the "
    "fallback for TFRecords"))
SCENARIONET = register_reader(Reader(
    "scenarionet", "file", read_scenarionet_file, suffixes=(".pkl",),
    description="ScenarioNet scenario pickles (WOMD, nuPlan, Argoverse 2 ...)"))
