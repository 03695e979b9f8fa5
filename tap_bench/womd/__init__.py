"""Waymo Open Motion Dataset (WOMD) files, read and written without TensorFlow.

Modules, in the order data flows:

- :mod:`~tap_bench.womd.checksum`: CRC-32C (the ``crc32c`` package, or a numpy fallback);
- :mod:`~tap_bench.womd.tfrecord`: TFRecord framing, plain or GZIP, record by record;
- :mod:`~tap_bench.womd.proto`: the ``Scenario`` message classes, built at run time;
- :mod:`~tap_bench.womd.scenario`: a ``Scenario`` record to the trajectory table;
- :mod:`~tap_bench.womd.tf_example`: the ``tf.Example`` motion format to the table;
- :mod:`~tap_bench.womd.writer`: a trajectory table back to ``Scenario`` TFRecords;
- :mod:`~tap_bench.womd.trajectory_types`: Waymo's trajectory-type classifier, a reference
  for TAP labels;
- :mod:`~tap_bench.womd.validation`: TAP labels validated against it (``tap-bench
  validate``).

Reading many files, and other formats (ScenarioNet pickles of WOMD, nuPlan or Argoverse 2),
is :mod:`tap_bench.sources`, whose registered readers use these decoders.
"""

from tap_bench.errors import WomdRecordError
from tap_bench.womd.trajectory_types import classify_trajectories
from tap_bench.womd.writer import write_womd

__all__ = [
    "WomdRecordError",
    "classify_trajectories",
    "write_womd",
]
