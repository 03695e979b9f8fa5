"""A recorded WOMD scenario ready to drive in: its tracks as arrays, its road map, its ego.

:func:`scene_catalog` lists the scenarios of some files (a seed of ``tap_bench/womd-v0`` is
an index into it, in file and record order); :func:`load_scene` decodes one into a
:class:`Scene`: every track as (n_tracks, n_steps) arrays in WOMD's axes, the
:class:`~tap_bench.womd.roadmap.RoadMap` with its topology, the ego's row (the SDC, or a track
named by id) and the scenario's content hash (the key of the episode cache).

Bad data gets :class:`SceneError`, which names the scenario (or file and record) and says
what to do: no SDC, an ego not valid at the current time, no lanes.
"""

from __future__ import annotations

import functools
import hashlib
import os
import warnings
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tap_bench.errors import ParameterError, TapBenchError

if TYPE_CHECKING:
    import numpy as np
    import pandas as pd

if TYPE_CHECKING:  # read with a scene only: resolving a suite needs no protobuf
    from tap_bench.womd.roadmap import RoadMap

__all__ = ["CURRENT_STEP", "TRAFFIC", "Scene", "SceneError", "SceneRef", "WomdScenes",
           "load_scene", "scene_catalog"]

TRAFFIC = ("log", "idm", "constant-velocity")
"""Traffic modes: ``log`` replays every other agent (non-reactive), ``idm`` drives the
vehicles with IDM/MOBIL along the lanes they drove (reactive), ``constant-velocity`` moves
every agent valid at the current time on at its velocity then (the realism score's floor)."""

CURRENT_STEP = 10
"""The current time of a WOMD scenario, as a step (1.0 s at 10 Hz): the policy drives from
here; before it everything replays the log."""


class SceneError(TapBenchError, ValueError):
    """A scenario that cannot become a closed-loop scene (the message names it and the fix)."""


@dataclass(frozen=True)
class SceneRef:
    """Where one scenario is: a file, the record in it (0 for a one-scenario file), its
    reader's name, and the byte offset of the record's header (-1: unknown), which lets a
    scene be read without the records before it."""

    path: str
    record: int
    format: str
    offset: int = field(default=-1, compare=False)

    def __str__(self) -> str:
        return (f"{self.path} record {self.record}" if self.format != "scenarionet"
            else self.path)

    def digest(self) -> str:
        """SHA-256 of the scenario's bytes (its record, or the whole pickle): the content
        hash an episode cache keys a recorded scene on."""
        if self.format == "scenarionet":
            return hashlib.sha256(Path(self.path).read_bytes()).hexdigest()
        return hashlib.sha256(_record_of(self).data).hexdigest()


def _record_of(ref: SceneRef) -> Any:
    """The TFRecord record ``ref`` names (read at its offset where known)."""
    from tap_bench.womd.tfrecord import iter_records, read_record

    if ref.offset >= 0:
        return read_record(ref.path, ref.record, ref.offset)
    for record in iter_records(ref.path):
        if record.index == ref.record:
            return record
    raise SceneError(f"{ref.path}: no record {ref.record}; the file changed since it was "
                     "listed.")


@dataclass(frozen=True)
class Scene:
    """One recorded scenario as arrays.

    Attributes:
        scenario_id: WOMD's id.
        ref: where it came from.
        times: (T,) [s].
        track_ids, object_types: (n,) str.
        x, y, heading, vx, vy, speed: (n, T) in WOMD's axes [m, rad, m/s]; NaN where
            invalid.
        valid: (n, T) bool.
        length, width: (n,) [m] (the track's median over its valid steps).
        ego: the ego's row.
        road: the road map.
    """

    scenario_id: str
    ref: SceneRef
    times: np.ndarray
    track_ids: np.ndarray
    object_types: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    speed: np.ndarray
    valid: np.ndarray
    length: np.ndarray
    width: np.ndarray
    ego: int
    road: RoadMap

    @property
    def digest(self) -> str:
        """SHA-256 of the scenario's bytes (the record or the file), read again from
        :attr:`ref` when asked (:meth:`SceneRef.digest`): a rollout never asks, and keeping
        the bytes for it would hold them as long as the scene."""
        return self.ref.digest()

    @property
    def n_steps(self) -> int:
        """Steps in the record."""
        return len(self.times)

    def table(self) -> pd.DataFrame:
        """The record as a trajectory table (every track, every step, WOMD axes)."""
        import numpy as np
        import pandas as pd

        n, t = self.x.shape
        return pd.DataFrame({
            "scenario_id": np.full(n * t, self.scenario_id, dtype=object),
            "track_id": np.repeat(self.track_ids, t),
            "t": np.tile(self.times - self.times[0], n),
            "x": self.x.ravel(), "y": self.y.ravel(), "heading": self.heading.ravel(),
            "speed": self.speed.ravel(), "valid": self.valid.ravel(),
            "vx": self.vx.ravel(), "vy": self.vy.ravel(),
            "object_type": np.repeat(self.object_types, t),
            "is_ego": np.repeat(np.arange(n) == self.ego, t),
            "source": np.full(n * t, "womd", dtype=object),
            "length": np.repeat(self.length, t), "width": np.repeat(self.width, t)})


def scene_catalog(paths: str | os.PathLike | Iterable[str | os.PathLike]) -> list[SceneRef]:
    """Every scenario of some files, in file and record order (a seed is an index into it).

    Files in a folder or matched by a pattern that are not WOMD records (a README, an empty
    file) are left out with a warning, once per file, as ``tap-bench ingest`` leaves them
    out (:func:`tap_bench.sources.ingest.record_files`). A scenario id met again (the same
    scenario in two files, or twice in one) is listed once, where it is first met, with a
    warning naming both places.

    Raises:
        FileFormatError: a pattern that matches nothing (or nothing but files that are not
            records), a file of an unknown format.
        SceneError: a file named on its own that holds no scenario (an empty file).
    """
    from tap_bench.sources.ingest import record_files

    refs: list[SceneRef] = []
    first: dict[str, SceneRef] = {}
    for path in record_files(paths, note=_note_once):
        listed = _file_scenarios(str(path), *_stamp(path))
        if not listed:
            raise SceneError(f"{path}: no scenario in this file (it is empty or holds no "
                             "records), so there is nothing to drive. Leave the file out.")
        for ref, sid in listed:
            if sid and sid in first:
                _note_once(f"scenario {sid} is in {first[sid]} and again in {ref}: it is "
                           f"run once, from {first[sid]}. Leave one of the copies out.")
                continue
            if sid:
                first[sid] = ref
            refs.append(ref)
    return refs


def _stamp(path: Path) -> tuple[int, int]:
    stat = path.stat()
    return stat.st_size, stat.st_mtime_ns


@functools.lru_cache(maxsize=256)
def _file_scenarios(path: str, size: int, mtime_ns: int) -> tuple[tuple[SceneRef, str], ...]:
    """The scenarios of one file, each with its scenario id ("" where the id cannot be read
    without decoding it); cached per file and state (size, modification time)."""
    from tap_bench.sources.ingest import _file_format
    from tap_bench.womd.tfrecord import iter_records

    name = _file_format(Path(path), "auto", True).name
    if name == "scenarionet":
        return ((SceneRef(path, 0, name), _scenarionet_id(path)),)
    if name not in ("scenario", "tf_example"):
        raise SceneError(f"{path}: format {name!r} carries no map; closed-loop scenes "
                         "need WOMD Scenario, tf.Example or ScenarioNet files.")
    return tuple((SceneRef(path, record.index, name, record.offset),
                  _record_id(record.data, name))
                 for record in iter_records(path))


def _record_id(data: bytes, format: str) -> str:
    """The scenario id a record holds ("" when it cannot be read: decoding says why)."""
    try:
        if format == "scenario":
            from tap_bench.womd.proto import ScenarioView

            return str(ScenarioView.FromString(data).scenario_id)
        from tap_bench.womd.tf_example import Example

        feature = Example.FromString(data).features.feature.get("scenario/id")
        values = feature.bytes_list.value if feature is not None else ()
        return values[0].decode() if len(values) else ""
    except Exception:  # a damaged record: load_scene names it and what is wrong
        return ""


def _scenarionet_id(path: str) -> str:
    """The scenario id of a ScenarioNet pickle ("" when it cannot be read)."""
    try:
        from tap_bench.sources.scenarionet import load_scenarionet

        scenario = load_scenarionet(path)
        meta = scenario.get("metadata", {}) or {}
        return str(meta.get("scenario_id", scenario.get("id", Path(path).stem)))
    except Exception:  # a damaged pickle: load_scene names it and what is wrong
        return ""


_NOTED: set[str] = set()


def _note_once(text: str) -> None:
    """Warn about a file left out of a catalogue once per process (a catalogue is listed
    by every env and run that reads the files)."""
    if text not in _NOTED:
        _NOTED.add(text)
        warnings.warn(text, UserWarning, stacklevel=4)


_CONTRACT_FIX = ("A closed-loop scene is built only from records that keep the trajectory "
                 "contract (SPEC section 1), as tap-bench ingest reads them; leave the "
                 "scenario out (the other scenes still run).")


def _read(ref: SceneRef) -> tuple[_Columns, RoadMap]:
    """Decode ``ref`` into (its trajectory table's columns, road map), its
    tracks checked as ``tap-bench ingest`` checks each scenario it reads.

    Raises:
        WomdRecordError: the record cannot be decoded, or its table breaks the trajectory
            contract (a NaN, infinite or far-off state on a valid row, NaN or backward
            times ...): the message names the file, the record, the track, the column and
            the value.
    """
    from tap_bench.errors import WomdRecordError
    from tap_bench.sources.ingest import _frame_contract_problem, _scenario_id
    from tap_bench.sources.scenarionet import decode_scenarionet, load_scenarionet
    from tap_bench.womd import roadmap
    from tap_bench.womd.scenario import decode_scenario
    from tap_bench.womd.tf_example import decode_tf_example

    def checked(table: Any, record: int, offset: int) -> _Columns:
        if _keeps_contract(table):  # seen on its arrays: no pandas table needed
            return _ArrowColumns(table)
        frame = table.to_pandas()
        problem = _frame_contract_problem(frame, _scenario_id(table)) if len(frame) else None
        if problem:
            raise WomdRecordError(ref.path, record, offset, problem.rstrip("."), _CONTRACT_FIX)
        return _FrameColumns(frame)

    if ref.format == "scenarionet":
        scenario = load_scenarionet(ref.path)
        table = checked(decode_scenarionet(scenario, path=ref.path), 0, 0)
        road = roadmap.scenarionet_road_map(scenario, source=ref.path)
        return table, road
    record = _record_of(ref)
    if ref.format == "scenario":
        table = checked(decode_scenario(record), record.index, record.offset)
        road = roadmap.scenario_road_map(record.data, source=str(ref))
    else:
        table = checked(decode_tf_example(record), record.index, record.offset)
        road = roadmap.tf_example_road_map(record.data, source=str(ref))
        if road is None:
            road = roadmap.RoadMap(str(table.first("scenario_id")), {}, topology="none")
    return table, road


def load_scene(ref: SceneRef, *, ego: str = "sdc") -> Scene:
    """Decode one scenario into a :class:`Scene`.

    Args:
        ref: from :func:`scene_catalog`.
        ego: ``"sdc"`` (the self-driving car) or a track id.

    Raises:
        SceneError: no SDC (or no such track), an ego not valid at the current time, a
            record too short for a current time, no lanes; the message names the scenario.
        WomdRecordError: the record cannot be decoded.
    """
    import numpy as np

    table, road = _read(ref)
    sid = str(table.first("scenario_id")) if len(table) else road.scenario_id
    where = f"scenario {sid} ({ref})"
    tracks = table.tracks()
    n = len(tracks)
    if n == 0:
        raise SceneError(f"{where}: no tracks.")
    t = len(table) // n
    if t <= CURRENT_STEP + 1:
        raise SceneError(f"{where}: {t} steps; a closed-loop scene needs more than "
                         f"{CURRENT_STEP + 1} (1.0 s of history, then the future). Leave it out.")

    def grid(col: str) -> np.ndarray:
        return table.values(col, float).reshape(n, t)

    valid = table.values("valid", bool).reshape(n, t)
    is_ego = table.values("is_ego", bool).reshape(n, t)[:, 0]
    if ego == "sdc":
        rows = np.flatnonzero(is_ego)
        if not len(rows):
            raise SceneError(f"{where}: no self-driving car (no sdc_track_index / sdc_id). "
                             "Name a track to drive with --ego TRACK_ID (ego='ID').")
        row = int(rows[0])
    else:
        rows = np.flatnonzero(tracks.astype(str) == str(ego))
        if not len(rows):
            raise SceneError(f"{where}: no track {ego!r}; its tracks are "
                             f"{', '.join(map(str, tracks[:10]))}{' ...' if n > 10 else ''}.")
        row = int(rows[0])
    if not valid[row, CURRENT_STEP]:
        raise SceneError(f"{where}: the ego (track {tracks[row]}) is not valid at the current "
                         "time (1.0 s), so nothing can take it over there. Choose another "
                         "track with --ego, or leave the scenario out.")
    object_types = table.per_track("object_type", n, t)
    if object_types[row] != "vehicle":
        raise SceneError(f"{where}: the ego (track {tracks[row]}) is not a vehicle.")
    from tap_bench.sim.womd_lanes import lane_points

    if not any(lane_points(lane.centre) is not None for lane in road.lanes.values()):
        raise SceneError(f"{where}: the map has no lanes (of two distinct points or more), so "
                         "there is no road to drive on. Use files with a map (Scenario "
                         "protos, ScenarioNet pickles, tf.Examples with roadgraph_samples).")
    x, y = grid("x"), grid("y")
    heading, vx, vy = grid("heading"), grid("vx"), grid("vy")
    speed = grid("speed")
    sizes = {}
    for col, default in (("length", 4.8), ("width", 2.0)):
        values = grid(col) if col in table.names else np.full((n, t), np.nan)
        with np.errstate(invalid="ignore"):
            values = np.where(valid & np.isfinite(values) & (values > 0), values, np.nan)
        sizes[col] = _row_medians(values, default)
    times = table.values("t", float)[:t]
    return Scene(sid, ref, times, tracks.astype(str), object_types.astype(str), x, y,
                 heading, vx, vy, speed, valid, sizes["length"], sizes["width"], row, road)


class _Columns:
    """The reads :func:`load_scene` makes of a decoded scenario's trajectory table (one
    row per track per step, track by track)."""

    names: tuple[str, ...]

    def __len__(self) -> int:
        raise NotImplementedError

    def first(self, name: str) -> Any:
        """The column's value on the first row."""
        raise NotImplementedError

    def tracks(self) -> Any:
        """The track ids in the order first met (``pandas.unique``)."""
        raise NotImplementedError

    def values(self, name: str, dtype: type) -> np.ndarray:
        """(rows,) the column as ``dtype``."""
        raise NotImplementedError

    def per_track(self, name: str, n: int, t: int) -> np.ndarray:
        """(n,) the column on each track's first row (n tracks of t rows each)."""
        raise NotImplementedError


class _FrameColumns(_Columns):
    """A table checked through pandas (:func:`tap_bench.trajectories.validate_and_index`)."""

    def __init__(self, frame: pd.DataFrame) -> None:
        self.frame = frame
        self.names = tuple(frame.columns)

    def __len__(self) -> int:
        return len(self.frame)

    def first(self, name: str) -> Any:
        return self.frame[name].iloc[0]

    def tracks(self) -> Any:
        import pandas as pd

        return pd.unique(self.frame["track_id"])

    def values(self, name: str, dtype: type) -> np.ndarray:
        return self.frame[name].to_numpy(dtype)

    def per_track(self, name: str, n: int, t: int) -> np.ndarray:
        return self.frame[name].to_numpy().reshape(n, t)[:, 0]


class _ArrowColumns(_Columns):
    """A decoded Arrow table :func:`_keeps_contract` passed: its columns read as arrays."""

    def __init__(self, table: Any) -> None:
        self.table = table
        self.names = tuple(table.column_names)

    def __len__(self) -> int:
        return self.table.num_rows

    def first(self, name: str) -> Any:
        return self.table.column(name)[0].as_py()

    def tracks(self) -> Any:
        import pandas as pd
        import pyarrow.compute as pc

        # as pandas.unique gives them of the column pandas makes of Arrow strings
        return pd.array(pc.unique(self.table.column("track_id")),
                        dtype=pd.api.types.pandas_dtype(str))

    def values(self, name: str, dtype: type) -> np.ndarray:
        import numpy as np

        return np.asarray(self.table.column(name).to_numpy(), dtype=dtype)

    def per_track(self, name: str, n: int, t: int) -> np.ndarray:
        import numpy as np

        column = self.table.column(name).take(np.arange(n, dtype=np.int64) * t)
        return column.to_numpy(zero_copy_only=False)


def _keeps_contract(table: Any) -> bool:
    """Whether a decoded scenario's Arrow table keeps the trajectory contract on sight of
    its arrays, its kinematics and sizes float64 (:func:`tap_bench.trajectories.
    plainly_valid`); one that does not goes through pandas' check, which names what is
    wrong."""
    from tap_bench.trajectories import plainly_valid

    return plainly_valid(table, floats=("length", "width"))


def _row_medians(values: np.ndarray, default: float) -> np.ndarray:
    """(n,) the median of each row of ``values`` (n, T) over its non-NaN entries (the mean
    of the two middle ones for an even count); ``default`` for a row of NaN only."""
    import numpy as np

    ordered = np.sort(values, axis=1)  # NaN last
    count = (~np.isnan(values)).sum(axis=1)
    rows = np.arange(len(values))
    lo, hi = ordered[rows, np.maximum(count - 1, 0) // 2], ordered[rows, count // 2]
    return np.where(count > 0, np.where(count % 2 == 1, lo, (lo + hi) / 2), default)


@dataclass(frozen=True)
class WomdScenes:
    """Recorded scenes to drive in: what a rollout or a suite names instead of a synthetic
    scenario.

    Attributes:
        files: WOMD files (Scenario or tf.Example TFRecords, ScenarioNet pickles), patterns
            or folders.
        traffic: ``"log"`` or ``"idm"``.
        ego: ``"sdc"`` or a track id.
        policy_frequency: decisions per second (the simulation runs at 10 Hz).
        name: the ``env`` column of the tables.
    """

    files: tuple[str, ...]
    traffic: str = "log"
    ego: str = "sdc"
    policy_frequency: int = 2
    name: str = "womd"
    config: Mapping[str, Any] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        if isinstance(self.files, str | os.PathLike):
            object.__setattr__(self, "files", (str(self.files),))
        object.__setattr__(self, "files", tuple(str(f) for f in self.files))
        if not self.files:
            raise ParameterError("files", self.files, "at least one WOMD file or pattern")
        if self.traffic not in TRAFFIC:
            raise ParameterError("traffic", self.traffic, f"one of {TRAFFIC}")
        if (not isinstance(self.policy_frequency, int) or self.policy_frequency <= 0
                or 10 % self.policy_frequency):
            raise ParameterError("policy_frequency", self.policy_frequency,
                                 "a divisor of 10 Hz (1, 2, 5 or 10)")
        if not str(self.ego):
            raise ParameterError("ego", self.ego, "'sdc' or a track id")

    @property
    def env_id(self) -> str:
        return "tap_bench/womd-v0"

    @property
    def max_steps(self) -> int:
        return 0

    def with_overrides(self, config: Mapping[str, Any] | None = None, **_: Any) -> WomdScenes:
        """The same scenes with more highway-env config (the observation a policy reads)."""
        merged = {**self.config, **(config or {})}
        return WomdScenes(self.files, self.traffic, self.ego, self.policy_frequency,
                          self.name, merged)

    def catalog(self) -> list[SceneRef]:
        """The scenarios, in seed order."""
        return scene_catalog(self.files)

    def seeds(self, spec: str | int | Iterable[int] | None = "all") -> tuple[int, ...]:
        """The seeds a rollout or suite runs on these scenes: ``"all"`` (or None) is every
        scenario's index; any other seeds (``"0-4"``, ``[1, 3]``) must name scenarios of
        the files.

        Raises:
            ParameterError: a seed beyond the files' scenarios (the env itself maps any
                seed onto a scene, ``seed % N``; a run names each scene once).
        """
        from tap_bench.sim.scenario_format import parse_seeds

        n = len(self.catalog())
        if spec is None or spec == "all":
            return tuple(range(n))
        seeds = tuple(parse_seeds(spec))
        beyond = [s for s in seeds if not 0 <= s < n]
        if beyond:
            raise ParameterError("seeds", beyond[0] if len(beyond) == 1 else beyond,
                                 f"0 to {n - 1}", message=(
                                     f"seeds {_listed(beyond)}: beyond the {n} scenario(s) "
                                     f"of {', '.join(self.files)} (seeds 0 to {n - 1}, one "
                                     "per scenario). Give seeds within them, or 'all'."))
        return seeds

    def fingerprint(self, ref: SceneRef) -> dict[str, Any]:
        """The env part of an episode-cache key (:func:`tap_bench.bench.cache.episode_key`)
        for the scenario ``ref``: its content hash and the settings that shape the episode,
        not its path (a renamed or moved file keeps its episodes)."""
        return {"womd": ref.digest(), "format": ref.format, "traffic": self.traffic,
                "ego": self.ego, "policy_frequency": self.policy_frequency,
                "config": dict(self.config)}


def _listed(values: list[int]) -> str:
    shown = ", ".join(map(str, values[:5]))
    return shown + (f" ... ({len(values)} seeds)" if len(values) > 5 else "")
