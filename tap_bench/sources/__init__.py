"""Driving data in: a registry of readers (format -> sniff, decode) and the streaming ingest
that turns files of any registered format into one trajectory table.

- :mod:`~tap_bench.sources.registry`: :class:`Reader` and :func:`register_reader`;
- :mod:`~tap_bench.sources.builtin`: WOMD ``Scenario`` and ``tf.Example`` TFRecords (decoded
  by :mod:`tap_bench.womd`), ScenarioNet pickles;
- :mod:`~tap_bench.sources.scenarionet`: ScenarioNet pickles through a restricted unpickler;
- :mod:`~tap_bench.sources.ingest`: many files, streamed, in worker processes, with a report;
- :mod:`~tap_bench.sources.maps`: the files' road maps (lanes, lines, edges) as a map table.
"""

from tap_bench.sources import builtin as _builtin  # noqa: F401 (registers the built-ins)
from tap_bench.sources.ingest import (
    IngestReport,
    check_reader,
    ingest_driving_data,
    ingest_womd,
    iter_driving_data,
    iter_womd,
    read_driving_data,
    read_womd,
)
from tap_bench.sources.registry import (
    READERS,
    Reader,
    get_reader,
    reader_names,
    readers,
    register_reader,
)

__all__ = ["READERS", "IngestReport", "Reader", "check_reader", "get_reader",
           "ingest_driving_data", "ingest_womd", "iter_driving_data", "iter_womd",
           "read_driving_data", "read_womd", "reader_names", "readers", "register_reader"]
