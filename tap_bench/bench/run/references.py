"""The coverage references of a suite run, read once before its episodes: each a label table
(checked at the suite's level), a label file, or driving-data files of any registered
format labelled with the suite's thresholds (:func:`read_references`; part of
:mod:`tap_bench.bench.run.runner`, scored by :mod:`~tap_bench.bench.run.scoring`)."""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Mapping, Sequence

import pandas as pd

from tap_bench.errors import ParameterError
from tap_bench.labelling import tap
from tap_bench.labels import validate_labels
from tap_bench.sources import read_womd
from tap_bench.tableio import read_table
from tap_bench.thresholds import Thresholds

__all__ = ["Corpora", "ReferenceSource", "read_references"]

Corpora = Mapping[str, tuple[pd.DataFrame | None, pd.DataFrame]]
"""The run's references read: name -> (trajectories or None, label table)."""

ReferenceSource = pd.DataFrame | str | os.PathLike | Sequence[str | os.PathLike]
"""A coverage reference: a label table, a label file, or driving-data files."""

_LABEL_SUFFIXES = (".parquet", ".pq", ".csv", ".csv.gz")


def _reference(name: str, source: ReferenceSource, level: str, thresholds: Thresholds
               ) -> tuple[pd.DataFrame | None, pd.DataFrame]:
    """(trajectories or None, label table) of one named reference."""
    if isinstance(source, pd.DataFrame):
        validate_labels(source, level, source=f"reference {name!r}")
        return None, source
    paths = [source] if isinstance(source, str | os.PathLike) else list(source)
    if not paths:
        raise ParameterError(f"references[{name!r}]", source, "a label table or data files")
    if len(paths) == 1 and str(paths[0]).lower().endswith(_LABEL_SUFFIXES):
        table = read_table(paths[0])
        if "sdl" in table.columns:  # a label file
            validate_labels(table, level, source=str(paths[0]))
            return None, table
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        traj = read_womd([str(p) for p in paths])
        labels = tap(traj, thresholds, source=name).labels("all")
    return traj, labels


def read_references(sources: Mapping[str, ReferenceSource], level: str,
                    thresholds: Thresholds, timings: dict[str, float]
                    ) -> dict[str, tuple[pd.DataFrame | None, pd.DataFrame]]:
    """name -> (trajectories or None, label table) of every reference: label tables checked
    at ``level``, driving data labelled with ``thresholds``; the time it took goes to
    ``timings["references"]`` [s]."""
    t0 = time.perf_counter()
    corpora = {name: _reference(name, source, level, thresholds)
               for name, source in sources.items()}
    if corpora:
        timings["references"] = time.perf_counter() - t0
    return corpora
