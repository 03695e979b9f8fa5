"""Waymo Open Motion Dataset (WOMD) files, read and written without TensorFlow.

Modules, in the order data flows:

- :mod:`~tap_bench.womd.checksum`: CRC-32C (the ``crc32c`` package, or a numpy fallback);
- :mod:`~tap_bench.womd.tfrecord`: TFRecord framing, plain or GZIP, record by record;
- :mod:`~tap_bench.womd.proto`: the ``Scenario`` message classes, built at run time;
- :mod:`~tap_bench.womd.scenario`: a ``Scenario`` record to the trajectory table;
- :mod:`~tap_bench.womd.tf_example`: the ``tf.Example`` motion format to the table;
- :mod:`~tap_bench.womd.scenarionet`: ScenarioNet pickles, through a restricted unpickler;
- :mod:`~tap_bench.womd.writer`: a trajectory table back to ``Scenario`` TFRecords;
- :mod:`~tap_bench.womd.ingest`: many files, streamed, in worker processes, with a report;
- :mod:`~tap_bench.womd.trajectory_types`: Waymo's trajectory-type classifier, a reference
  for TAP labels.
"""

from tap_bench.errors import WomdRecordError
from tap_bench.womd.ingest import IngestReport, ingest_womd, iter_womd, read_womd
from tap_bench.womd.trajectory_types import classify_trajectories
from tap_bench.womd.writer import write_womd

__all__ = [
    "IngestReport",
    "WomdRecordError",
    "classify_trajectories",
    "ingest_womd",
    "iter_womd",
    "read_womd",
    "write_womd",
]
