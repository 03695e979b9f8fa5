"""The registry of driving-data readers: a format name -> how to recognise a file of it and
how to decode it into the trajectory table.

Two framings exist:

- ``"tfrecord"``: a file of TFRecord records (plain or GZIP), one scenario per record; the
  reader's ``decode(record, object_types)`` takes a :class:`tap_bench.womd.tfrecord.Record`
  and its ``sniff(payload)`` looks at the first record's bytes;
- ``"file"``: one scenario per file (a ScenarioNet pickle); ``decode(path, object_types)``
  takes the path and the reader claims files by their ``suffixes``.

``decode`` returns a pyarrow Table with :data:`tap_bench.womd.scenario.SCENARIO_COLUMNS`
and raises :class:`~tap_bench.errors.WomdRecordError` (file, record, offset, problem, fix)
for input it cannot read. Functions must be module-level (they are sent to worker processes
by reference). Add a format with :func:`register_reader` (docs/contributing.md shows one).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import pyarrow as pa

from tap_bench.errors import ParameterError, did_you_mean
from tap_bench.registry import Registry

__all__ = ["FRAMINGS", "READERS", "Reader", "get_reader", "reader_names", "readers",
           "register_reader"]

FRAMINGS = ("tfrecord", "file")


@dataclass(frozen=True)
class Reader:
    """A data format tap-bench can ingest.

    Attributes:
        name: the format's name (``--format NAME``).
        framing: ``"tfrecord"`` or ``"file"`` (module docstring).
        decode: record (or path) and the object types to keep (None: all) -> pa.Table.
        sniff: for ``"tfrecord"`` readers, first record's payload (bytes) -> True when the
            file is in this format; tried in registration order, the last reader registered
            with ``sniff=None`` is the fallback.
        suffixes: for ``"file"`` readers, the file name endings it claims (``".pkl"``).
        description: one line for ``tap-bench ingest --help``.
    """

    name: str
    framing: str
    decode: Callable[[Any, frozenset[str] | None], pa.Table]
    sniff: Callable[[bytes], bool] | None = None
    suffixes: tuple[str, ...] = field(default=())
    description: str = ""

    def __post_init__(self) -> None:
        if not self.name or not isinstance(self.name, str) or self.name == "auto":
            raise ParameterError("Reader.name", self.name, "a non-empty name other than 'auto'")
        if self.framing not in FRAMINGS:
            raise ParameterError("Reader.framing", self.framing, f"one of {FRAMINGS}")
        if not callable(self.decode):
            raise ParameterError("Reader.decode", self.decode, "a function")
        if self.framing == "file" and not self.suffixes:
            raise ParameterError("Reader.suffixes", self.suffixes,
                                 "at least one file ending for a 'file' reader")


READERS: Registry[Reader] = Registry("format")
"""The registered data formats, in registration order (:class:`tap_bench.registry.Registry`:
a name registered twice is refused)."""


def register_reader(reader: Reader) -> Reader:
    """Add a format; a name already taken is refused (readers are global to the process:
    name the module that registers one as a plugin, :mod:`tap_bench.plugins`, to have it on
    the command line and in every worker).

    Raises:
        RegistrationError: the name is taken.
    """
    if not isinstance(reader, Reader):
        raise ParameterError("register_reader(reader)", reader, "a tap_bench.sources.Reader")
    return READERS.register(reader)


def readers() -> list[Reader]:
    """The registered readers, in registration order."""
    return list(READERS)


def reader_names() -> tuple[str, ...]:
    """The registered formats' names."""
    return READERS.names()


def get_reader(name: str) -> Reader:
    """The reader of format ``name`` (with "did you mean" when unknown)."""
    if name not in READERS:
        raise did_you_mean("format", name, ("auto", *READERS.names()))
    return READERS[name]
