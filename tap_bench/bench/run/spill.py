"""A run's per-episode tables on disk, one part per episode and table, instead of in memory.

A suite run over recorded scenes keeps none of an episode's tables in memory once its result
has arrived: :class:`RunSpill` takes each task result as it arrives (:meth:`RunSpill.keep`),
writes its trajectories, labels, segments, interaction-context occurrences and episode row
to Parquet parts in a folder beside the run folder, and keeps only the result's few scalars
(timings, cache flags, whether the episode ran) and the episode's ids, so the run's memory
does not grow with its scenes' rows. Afterwards each table is read from its parts as a
:class:`SpilledTable`: joined into one Parquet file a row group at a time
(:meth:`SpilledTable.write`), in the run's episode order, giving the file an in-memory run
writes; read back whole only where a step needs every row (the episode table and the
occurrences, one row per episode or a few, for the scores); or read a few episodes at a time
(:meth:`SpilledTable.table` with ``indices``: the replay viewer's chunks, the matching of
one scene against a reference).

The folder is the run's own (a fresh hidden folder beside the output, naming the process
that made it in its ``owner`` file: its id, host and start) and is removed when the run ends
(:meth:`RunSpill.close`), or when the spill is dropped (a run that raised) or the
interpreter exits. A run killed outright (``kill -9``, a machine that stopped) cannot
remove it: the next run into the same output removes the folders of that output whose
process is gone (the episodes an earlier run finished come back from the episode cache,
not from these parts).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import weakref
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tap_bench.tableio import owner_gone
from tap_bench.tableio import owner_line as _owner
from tap_bench.tableio import process_started as _started  # noqa: F401 (its tests read it)

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["SPILLED", "RunSpill", "SpilledEpisodes", "SpilledTable"]

SPILLED = ("trajectories", "labels", "segments", "contexts", "episodes")
"""The tables of a task result (:func:`tap_bench.bench.run.tasks._label_together`) a spill
writes to disk."""


class RunSpill:
    """The per-episode parts of one run (module docstring).

    Args:
        output: the run folder the parts go beside (as ``.<name>.episodes-*``).

    Attributes:
        parts: table name -> {task index -> its part}, for the episodes with rows.
        rows: table name -> rows spilled so far.
        maps: ``map_id`` -> the index of its part of the ``roads`` table (the run's map
            table, :meth:`keep_maps`).
        scenes: task index -> (the episode's ``scenario_id`` in the run, its WOMD scenario
            id or None), for the episodes with trajectories.
        boxes: env -> [x min, y min, x max, y max] of its trajectories' positions [m].
    """

    def __init__(self, output: str | os.PathLike) -> None:
        output = Path(output)
        output.parent.mkdir(parents=True, exist_ok=True)
        _remove_abandoned(output)
        self.folder = Path(tempfile.mkdtemp(prefix=f".{output.name}.episodes-",
                                            dir=output.parent))
        (self.folder / "owner").write_text(_owner(os.getpid()) + "\n")
        self.parts: dict[str, dict[int, Path]] = {name: {} for name in (*SPILLED, "roads")}
        self.rows: dict[str, int] = dict.fromkeys((*SPILLED, "roads"), 0)
        self.scenes: dict[int, tuple[str, str | None]] = {}
        self.boxes: dict[str, list[float]] = {}
        self.maps: dict[str, int] = {}
        # removed with the spill too when the run raises (its frame, and so the spill, go)
        self._remove = weakref.finalize(self, shutil.rmtree, self.folder, True)

    def keep(self, index: int, result: dict[str, Any]) -> dict[str, Any]:
        """Write the tables of task result ``index`` (those of :data:`SPILLED` it has, with
        rows) to parts; the result without them, with ``ok``: whether every row of its
        episode table has status ``ok``."""
        episodes = result.get("episodes")
        kept = {**result, **dict.fromkeys(SPILLED)}
        kept["ok"] = bool(episodes is not None and len(episodes)
                          and (episodes["status"] == "ok").all())
        for name in SPILLED:
            table = result.get(name)
            if table is not None and len(table):
                self._write(name, index, table)
        trajectories = result.get("trajectories")
        if trajectories is not None and len(trajectories):
            self._note_scene(index, trajectories)
        return kept

    def _write(self, name: str, index: int, table: pd.DataFrame) -> None:
        from tap_bench.tableio import atomic_path

        path = self.folder / f"{name}-{index:08d}.parquet"
        with atomic_path(path) as tmp:
            table.to_parquet(tmp, index=False)
        self.parts[name][index] = path
        self.rows[name] += len(table)

    def keep_maps(self, tables: Iterable[pd.DataFrame]) -> SpilledTable:
        """Write map tables (a recorded scene's, or an env's road: one ``map_id`` each, or a
        few) to parts of the run's ``roads`` table, one at a time, in order; the table."""
        for table in tables:
            if not len(table):
                continue
            index = len(self.parts["roads"])
            self._write("roads", index, table)
            for map_id in table["map_id"].astype(str).unique():
                self.maps.setdefault(map_id, index)
        return self.table("roads")

    def _note_scene(self, index: int, trajectories: pd.DataFrame) -> None:
        """The episode's ids and its env's box, from its trajectories."""
        first = trajectories.iloc[0]
        womd = first.get("womd_scenario_id") if "womd_scenario_id" in trajectories else None
        self.scenes[index] = (str(first["scenario_id"]),
                              None if womd is None else str(womd))
        if "env" not in trajectories.columns:
            return
        for env, part in trajectories.groupby("env", sort=False):
            box = [float(part["x"].min()), float(part["y"].min()),
                   float(part["x"].max()), float(part["y"].max())]
            old = self.boxes.get(str(env))
            self.boxes[str(env)] = box if old is None else [
                min(old[0], box[0]), min(old[1], box[1]), max(old[2], box[2]),
                max(old[3], box[3])]

    def table(self, name: str) -> SpilledTable:
        """The spilled table ``name`` (one of :data:`SPILLED`)."""
        return SpilledTable(self, name)

    def close(self) -> None:
        """Remove the parts and their folder (:attr:`parts` still names them)."""
        self._remove()


def _remove_abandoned(output: Path) -> None:
    """Remove the spill folders of ``output`` (``.<name>.episodes-*``, with the ``owner``
    file a spill writes: its process id, host and start) whose process on this host is gone,
    or whose process id now names a process that started later
    (:func:`tap_bench.tableio.owner_gone`); any other folder is left alone, a run's of
    another host on a shared file system among them."""
    for folder in output.parent.glob(f".{output.name}.episodes-*"):
        try:
            owner = (folder / "owner").read_text()
        except (OSError, UnicodeDecodeError):
            continue  # not one a spill made (or not yet named): left alone
        if owner_gone(owner):
            shutil.rmtree(folder, ignore_errors=True)


class SpilledTable:
    """One table of a :class:`RunSpill`: its parts in task order.

    Args:
        spill: the run's spill.
        name: the table (one of :data:`SPILLED`).
    """

    def __init__(self, spill: RunSpill, name: str) -> None:
        self.spill = spill
        self.name = name

    def __len__(self) -> int:
        return self.spill.rows[self.name]

    def _ordered(self, indices: Iterable[int] | None = None) -> list[Path]:
        parts = self.spill.parts[self.name]
        chosen = sorted(parts) if indices is None else sorted(i for i in set(indices)
                                                              if i in parts)
        return [parts[i] for i in chosen]

    def table(self, indices: Iterable[int] | None = None) -> pd.DataFrame | None:
        """The rows of the episodes ``indices`` (None: every episode), in task order, as
        one table, as the concatenation of the results' tables gives it (None: no rows)."""
        import pandas as pd

        parts = self._ordered(indices)
        if not parts:
            return None
        return pd.concat([pd.read_parquet(p) for p in parts], ignore_index=True)

    def write(self, path: str | os.PathLike) -> int:
        """Join the parts into one Parquet table at ``path`` (one part and one row group in
        memory at a time); the rows written."""
        from tap_bench.sim.rollout_stream import join_parquet

        return join_parquet(self._ordered(), Path(path))


class SpilledEpisodes:
    """A spilled run's trajectories, segments and maps as the replay viewer reads them, a
    few episodes at a time (:class:`tap_bench.bench.report.viewer.build.EpisodeParts`).

    Args:
        spill: the run's spill, its ``roads`` kept (:meth:`RunSpill.keep_maps`).
    """

    def __init__(self, spill: RunSpill) -> None:
        self.spill = spill
        self._index = {sid: i for i, (sid, _) in spill.scenes.items()}

    def scenes(self) -> dict[str, str | None]:
        """Episode ``scenario_id`` -> its WOMD scenario id (None: none), in run order."""
        return dict(self.spill.scenes[i] for i in sorted(self.spill.scenes))

    def boxes(self) -> dict[str, tuple[float, float, float, float]]:
        """env -> (x min, y min, x max, y max) of its positions [m]."""
        return {env: (b[0], b[1], b[2], b[3]) for env, b in self.spill.boxes.items()}

    def episodes(self, scenario_ids: Iterable[str]) -> tuple[pd.DataFrame | None,
                                                              pd.DataFrame | None]:
        """The trajectories and segments of these episodes, in run order."""
        indices = [self._index[sid] for sid in scenario_ids if sid in self._index]
        return (self.spill.table("trajectories").table(indices),
                self.spill.table("segments").table(indices))

    def map_of(self, map_id: str) -> pd.DataFrame | None:
        """The map table of ``map_id`` (None: none)."""
        import pandas as pd

        index = self.spill.maps.get(map_id)
        if index is None:
            return None
        table = pd.read_parquet(self.spill.parts["roads"][index])
        return table[table["map_id"].astype(str) == map_id]

    def map_ids(self) -> list[str]:
        """Every ``map_id`` with a map, in order."""
        return list(self.spill.maps)
