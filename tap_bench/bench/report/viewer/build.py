"""Writing the replay viewer: one folder that opens in a browser from disk.

::

    viewer/
      index.html        the page (no network, no server: open it from disk)
      viewer.js         the player, the episode list, the label timelines and the charts
      viewer.css
      data/index.js     the episode list, the road maps and the run's facts
      data/<chunk>.js   the episodes of one env and seed (every policy), loaded on demand

Browsers do not let a page opened from disk read files with ``fetch``; they do run
``<script>`` files beside it, so every data file is a script that hands its JSON to the
viewer (``TAPVIEW.index(...)``, ``TAPVIEW.chunk(...)``).
"""

from __future__ import annotations

import contextlib
import glob
import json
import os
import warnings
from collections.abc import Collection, Iterator, Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import pandas as pd

from tap_bench.bench.cache import memoised, table_digest
from tap_bench.bench.episodes import episode_table
from tap_bench.bench.measures import MEASURES, run_measures
from tap_bench.bench.report.viewer.data import (
    MAP_MARGIN,
    episode_chunks,
    episode_index,
    map_features,
    signal_field,
)
from tap_bench.bench.suite import suite_from_dict
from tap_bench.errors import ParameterError, TapBenchError, UnknownNameError
from tap_bench.labelling import tap
from tap_bench.maps import empty_map
from tap_bench.sources import iter_womd, read_womd
from tap_bench.sources.ingest import record_files
from tap_bench.sources.maps import iter_road_maps, read_maps
from tap_bench.tableio import atomic_folder
from tap_bench.thresholds import Thresholds

if TYPE_CHECKING:
    from tap_bench.bench.cache import EpisodeCache

__all__ = ["DEFAULT_VIEW_SCENARIOS", "MAX_VIEW_SCENARIOS", "STATIC_FILES", "EpisodeParts",
           "write_run_viewer", "write_viewer", "write_womd_viewer"]

STATIC_FILES = ("index.html", "viewer.js", "viewer.css")
"""The viewer's own files, package data of :mod:`tap_bench.bench.report.viewer`."""


def _script(call: str, name: str | None, doc: Any) -> str:
    text = json.dumps(doc, separators=(",", ":"), allow_nan=False)
    # a "</script>" inside a label must not end a script element that loads the file
    text = text.replace("</", "<\\/")
    head = f"{json.dumps(name)}," if name is not None else ""
    return f"TAPVIEW.{call}({head}{text});\n"


def write_viewer(output: str | os.PathLike, index: dict[str, Any],
                 chunks: dict[str, list[dict[str, Any]]]) -> Path:
    """Write the viewer folder from its documents (:mod:`tap_bench.bench.report.viewer.data`).

    Args:
        output: the folder to (re)write.
        index: the index document (``episodes``, ``maps``, ``run``).
        chunks: chunk name -> episode documents.

    Returns:
        the path of ``index.html``.

    Raises:
        OutputPathError: ``output`` exists and is not a viewer folder tap-bench wrote (a
            file, a link, any other folder: it is never replaced).
    """
    return _write_viewer(output, index, {name: _script("chunk", name, docs)
                                         for name, docs in chunks.items()})


def _write_viewer(output: str | os.PathLike, index: dict[str, Any],
                  scripts: Mapping[str, str] | Iterator[tuple[str, str]]) -> Path:
    """:func:`write_viewer` with the chunks as their script files' text (or as (name,
    text) pairs made one at a time, each written before the next is made; the index is
    written after the last, so a generator may still fill it)."""
    output = Path(output)
    static = resources.files("tap_bench.bench.report.viewer") / "static"
    # built beside the target and moved into place whole; an earlier viewer is replaced
    with atomic_folder(output, overwrite=True, kind="viewer") as tmp:
        data = tmp / "data"
        data.mkdir()
        for name in STATIC_FILES:
            (tmp / name).write_bytes((static / name).read_bytes())
        for name, text in (scripts.items() if isinstance(scripts, Mapping) else scripts):
            (data / f"{name}.js").write_text(text, encoding="utf-8")
        (data / "index.js").write_text(_script("index", None, index), encoding="utf-8")
    return output / "index.html"


def _env_boxes(trajectories: pd.DataFrame, margin: float) -> dict[str, tuple]:
    box = trajectories.groupby("env")[["x", "y"]].agg(["min", "max"])
    return {str(env): (r[("x", "min")] - margin, r[("y", "min")] - margin,
                       r[("x", "max")] + margin, r[("y", "max")] + margin)
            for env, r in box.iterrows()}


class EpisodeParts(Protocol):
    """A run's trajectories, segments and maps on disk, read a few episodes at a time
    (:class:`tap_bench.bench.run.spill.SpilledEpisodes`)."""

    def scenes(self) -> dict[str, str | None]:
        """Episode ``scenario_id`` -> its recorded scene's WOMD id (None: not recorded),
        for the episodes with trajectories, in run order."""

    def boxes(self) -> dict[str, tuple[float, float, float, float]]:
        """env -> (x min, y min, x max, y max) of its trajectories' positions [m]."""

    def episodes(self, scenario_ids: Collection[str]) -> tuple[pd.DataFrame,
                                                                pd.DataFrame | None]:
        """The trajectories and segments of these episodes, in run order."""

    def map_of(self, map_id: str) -> pd.DataFrame | None:
        """The map table of ``map_id`` (None: none)."""

    def map_ids(self) -> list[str]:
        """Every ``map_id`` with a map, in order."""


def write_run_viewer(output: str | os.PathLike, summary: dict[str, Any],
                     episodes: pd.DataFrame, trajectories: pd.DataFrame | EpisodeParts, *,
                     segments: pd.DataFrame | None = None, roads: pd.DataFrame | None = None,
                     novel_labels: pd.DataFrame | None = None,
                     cache: EpisodeCache | None = None) -> Path:
    """Write the replay viewer of a run (``bench run``, ``demo``).

    Args:
        output: the viewer folder (``<run>/viewer``).
        summary: the run's ``summary.json`` content (level, thresholds, suite, reference).
        episodes: the episode table.
        trajectories: the run's trajectory table, or its episodes on disk
            (:class:`EpisodeParts`, with their segments and maps): then each chunk is read,
            made and written before the next (:func:`_write_parts_viewer`).
        segments: the segment table (label timelines); None labels the egos again with the
            run's thresholds (runs written before ``segments.parquet`` existed).
        roads: the map table of the envs' roads; None builds each env's road again from
            the suite.
        novel_labels: the run's ``novel_labels`` table (marks novel episodes).
        cache: the episode cache: the episode data and maps of unchanged trajectories,
            segments and roads are read from it (:func:`tap_bench.bench.cache.memoised`;
            the same bytes), except for recorded scenes (their signals are read again from
            the WOMD files).

    Returns:
        the path of the viewer's ``index.html``.
    """
    if not isinstance(trajectories, pd.DataFrame):
        return _write_parts_viewer(output, summary, episodes, trajectories, novel_labels)
    level = str(summary.get("level", "maneuver"))
    if roads is None:
        roads = _rebuild_roads(summary, sorted(trajectories["env"].unique()))
    if segments is None:
        # labelled as the run labelled them: along the roads' lanes beyond the record
        segments = _ego_segments(trajectories, summary.get("thresholds", "paper"), level,
                                 roads)
    if "level" in segments.columns:
        segments = segments[segments["level"] == level]
    have = set(trajectories["scenario_id"].astype(str).unique())
    measures = run_measures(summary)
    eps, entries = episode_index(episodes, novel_labels=novel_labels, has_replay=have,
                                 measures=measures, scenes=_recorded_scenes(trajectories))
    boxes = _env_boxes(trajectories, MAP_MARGIN) if "env" in trajectories.columns else {}

    def build() -> tuple[dict[str, str], dict[str, Any]]:
        chunks = episode_chunks(trajectories, eps, segments)
        _add_run_signals(summary, chunks)
        maps = {str(env): map_features(sub, boxes.get(str(env)))
                for env, sub in roads.groupby("map_id", sort=True)}
        return {name: _script("chunk", name, docs) for name, docs in chunks.items()}, maps

    inputs = None if cache is None or _run_womd_files(summary) else {
        "trajectories": table_digest(trajectories), "segments": table_digest(segments),
        "roads": table_digest(roads), "chunks": table_digest(eps[["scenario_id", "chunk"]])}
    scripts, maps = memoised(cache, "viewer", inputs, build, _viewer_files, _files_viewer)
    for entry in entries:
        # highway-env: one road per env; recorded scenes: the map of the episode's WOMD
        # scenario (a run names its episodes "<WOMD id>/<policy>")
        womd = str(entry["id"]).rpartition("/")[0]
        entry["map"] = (entry["env"] if entry["env"] in maps else
                        womd if womd in maps else None)
    return _write_viewer(output, _index(summary, output, level, measures, entries, maps),
                         scripts)


def _index(summary: dict[str, Any], output: str | os.PathLike, level: str,
           measures: Any, entries: list[dict[str, Any]], maps: dict[str, Any]
           ) -> dict[str, Any]:
    """The viewer's index document of a run: the run (its name, suite, level, reference,
    creation time, measures), its episodes' entries and the maps the index holds."""
    suite = summary.get("suite", {})
    return {"run": {"name": str(summary.get("run", Path(output).parent.name)),
                    "suite": str(suite.get("name", "")), "level": level,
                    "reference": str(summary.get("reference_policy", "")),
                    "source": "highway-env", "created": str(summary.get("created", "")),
                    "measures": measures},
            "episodes": entries, "maps": maps}


def _write_parts_viewer(output: str | os.PathLike, summary: dict[str, Any],
                        episodes: pd.DataFrame, parts: EpisodeParts,
                        novel_labels: pd.DataFrame | None) -> Path:
    """:func:`write_run_viewer` of a run's episodes on disk, one chunk in memory at a time:
    each chunk's trajectories and segments read, its documents made (the ones
    :func:`episode_chunks` makes of the whole table), given their traffic signals (read
    from the suite's WOMD files in one pass) and written. A recorded scene's map goes with
    its episodes' documents (``map``), not in the index: the index holds only the maps of
    the envs' own roads."""
    level = str(summary.get("level", "maneuver"))
    scenes = parts.scenes()
    measures = run_measures(summary)
    eps, entries = episode_index(episodes, novel_labels=novel_labels, has_replay=scenes,
                                 measures=measures,
                                 scenes={s: w for s, w in scenes.items() if w is not None})
    boxes = {env: (b[0] - MAP_MARGIN, b[1] - MAP_MARGIN, b[2] + MAP_MARGIN,
                   b[3] + MAP_MARGIN) for env, b in parts.boxes().items()}
    recorded = {w for w in scenes.values() if w is not None}
    maps = {m: map_features(parts.map_of(m), boxes.get(m)) for m in parts.map_ids()
            if m in boxes and m not in recorded}  # an env's own road, drawn where it drove
    members: dict[str, list[str]] = {}  # chunk -> its episodes with trajectories
    for sid, chunk in zip(eps["scenario_id"].astype(str), eps["chunk"], strict=True):
        if sid in scenes:
            members.setdefault(chunk, []).append(sid)
    for entry in entries:
        entry["map"] = entry["env"] if entry["env"] in maps else None

    def chunk_scripts() -> Iterator[tuple[str, str]]:
        for chunk, road in _chunks_with_roads(summary, members, scenes):
            trajectories, segments = parts.episodes(members[chunk])
            if segments is not None and "level" in segments.columns:
                segments = segments[segments["level"] == level]
            docs = episode_chunks(trajectories, eps, segments).get(chunk, [])
            drawn: dict[str, list | None] = {}  # the scene's map, made once for its docs
            for doc in docs:
                womd = scenes.get(str(doc["id"]))
                if road is not None and road.scenario_id == womd:
                    doc["signals"] = signal_field(road.signals)
                if womd is not None and womd not in drawn:
                    table = parts.map_of(womd)
                    drawn[womd] = None if table is None else map_features(
                        table, boxes.get(womd))
                if womd is not None and drawn[womd] is not None:
                    doc["map"] = drawn[womd]
            yield chunk, _script("chunk", chunk, docs)

    return _write_viewer(output, _index(summary, output, level, measures, entries, maps),
                         chunk_scripts())


def _chunks_with_roads(summary: dict[str, Any], members: Mapping[str, list[str]],
                       scenes: Mapping[str, str | None]) -> Iterator[tuple[str, Any]]:
    """Each chunk of ``members`` once, with the road map (and traffic signals) of its
    recorded scene read again from the suite's WOMD files, or None (not a recorded scene,
    or its files gone: a warning says which, as :func:`_add_run_signals`). The files are
    read once, in their order, a record at a time."""
    by_scene: dict[str, list[str]] = {}
    for chunk, sids in members.items():
        womd = scenes.get(sids[0])
        if womd is not None:
            by_scene.setdefault(womd, []).append(chunk)
    done: set[str] = set()
    present = _present_files(summary) if by_scene else []
    if present:
        maps = iter_road_maps(present)
        try:
            for road in maps:
                for chunk in by_scene.pop(road.scenario_id, ()):
                    done.add(chunk)
                    yield chunk, road
                if not by_scene:
                    break
        except (TapBenchError, OSError, ValueError) as err:
            warnings.warn(f"the viewer shows no traffic signals: the run's WOMD files could "
                          f"not be read again ({err}).", UserWarning, stacklevel=3)
        finally:
            getattr(maps, "close", lambda: None)()
    for chunk in members:
        if chunk not in done:
            yield chunk, None


def _present_files(summary: dict[str, Any]) -> list[str]:
    """The suite's WOMD files that are still there, as the run read them (folders and
    globs leave out files that are not records); a warning names those gone."""
    found = _found(_run_womd_files(summary))
    gone = [f for f, paths in found.items() if not paths]
    if gone:
        warnings.warn(f"the viewer shows no traffic signals for the scenes of "
                      f"{', '.join(gone)}: the files are "
                      "gone; put them back where the suite names them to see the signals.",
                      UserWarning, stacklevel=4)
    if not any(found.values()):
        return []
    return [str(p) for p in record_files([f for f, paths in found.items() if paths],
                                         note=lambda text: None)]


def _found(files: Sequence[str]) -> dict[str, list[str]]:
    """Each of a suite's WOMD paths -> what is there of it now: a glob's matches, a file or a
    folder itself (:func:`~tap_bench.sources.ingest.record_files` reads a folder's records),
    nothing where it is gone."""
    return {f: (sorted(glob.glob(f)) if glob.has_magic(f) else [f] if Path(f).exists() else [])
            for f in files}


def _recorded_scenes(trajectories: pd.DataFrame) -> dict[str, str]:
    """Episode ``scenario_id`` -> the WOMD scenario id of the recorded scene it drove (a WOMD
    suite's run and ``rollout --womd`` tables keep it in ``womd_scenario_id``)."""
    if "womd_scenario_id" not in trajectories.columns:
        return {}
    pairs = trajectories[["scenario_id", "womd_scenario_id"]].dropna().drop_duplicates()
    return dict(zip(pairs["scenario_id"].astype(str), pairs["womd_scenario_id"].astype(str),
                    strict=True))


def _viewer_files(built: tuple[dict[str, str], dict[str, Any]]) -> dict[str, bytes]:
    scripts, maps = built
    return {"chunks.json": json.dumps(scripts).encode(),
            "maps.json": json.dumps(maps, allow_nan=False).encode()}


def _files_viewer(files: dict[str, bytes]) -> tuple[dict[str, str], dict[str, Any]]:
    return json.loads(files["chunks.json"]), json.loads(files["maps.json"])


def _run_womd_files(summary: dict[str, Any]) -> list[str]:
    """The WOMD files the suite's recorded scenes come from (their signals per step)."""
    files: list[str] = []
    for env in summary.get("suite", {}).get("envs", []):
        if isinstance(env, dict) and "womd" in env:
            paths = env["womd"] if isinstance(env["womd"], list) else [env["womd"]]
            files += [str(p) for p in paths]
    return list(dict.fromkeys(files))


def _ego_segments(trajectories: pd.DataFrame, thresholds: Any, level: str,
                  roads: pd.DataFrame | None = None) -> pd.DataFrame:
    """The egos' segment table at ``level`` (for run folders written before
    ``segments.parquet`` existed), along the lanes of ``roads`` (the run's map table) beyond
    the end of a record, as the runner labels them."""
    if isinstance(thresholds, dict):
        thresholds = Thresholds.from_dict(thresholds, source="summary.json thresholds")
    # the whole scene is labelled (the interaction axis needs the other vehicles), the
    # egos' segments kept, as the runner writes them
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        segments = tap(trajectories, thresholds, source="run trajectories",
                       interactions="ego",
                       map_table=roads if roads is not None and len(roads) else None
                       ).segments(level)
    ego = trajectories.loc[trajectories["is_ego"].fillna(False).to_numpy(bool),
                           ["scenario_id", "track_id"]].drop_duplicates()
    return segments.merge(ego, on=["scenario_id", "track_id"])


def env_roads(envs: Sequence[str]) -> pd.DataFrame:
    """The map table of the highway-env scenarios among ``envs`` (one road each, as a run
    records them); envs that are no scenario of the catalogue (recorded scenes, a table's
    own env names) get no map."""
    from tap_bench.errors import UnknownNameError
    from tap_bench.sim.roads import road_table
    from tap_bench.sim.scenario_env import get_scenario

    frames = []
    for env in envs:
        try:
            scenario = get_scenario(str(env))
        except UnknownNameError:
            continue
        frames.append(road_table(scenario))
    return pd.concat(frames, ignore_index=True) if frames else empty_map()


def _rebuild_roads(summary: dict[str, Any], envs: Sequence[str]) -> pd.DataFrame:
    if summary.get("format") == "tap-bench-compare":  # two tables, no suite: as compare
        return env_roads(envs)  # drew them (recorded scenes have no map there)
    # a run folder is data: the plugins its suite names are not imported (the user names
    # plugins with --plugin), and an env only a plugin defines gets no map
    doc = summary.get("suite", {})
    if isinstance(doc, dict):
        doc = {k: v for k, v in doc.items() if k not in ("plugins", "gate")}
    suite = suite_from_dict(doc, source="summary.json", check_names=False)
    frames = []
    for env in envs:
        if env in suite.envs:
            with contextlib.suppress(UnknownNameError):
                frames.append(suite.road(env))
    return pd.concat(frames, ignore_index=True) if frames else empty_map()


DEFAULT_VIEW_SCENARIOS = 100
"""Scenarios the viewer of WOMD files shows by default: the first ones of the files, read
one record at a time (a scenario costs about 14 MB while the viewer is built; a whole
shard of 500 would take 7 GB)."""
MAX_VIEW_SCENARIOS = 1000
"""The most scenarios one viewer of WOMD files may show (``max_scenarios``)."""


def _first_scenarios(paths: Sequence[str | os.PathLike], max_scenarios: int
                     ) -> tuple[pd.DataFrame, bool]:
    """The trajectory tables of the first ``max_scenarios`` scenarios of ``paths``, read
    one record at a time, and whether the files hold more."""
    tables, more = [], False
    records = iter_womd([str(p) for p in paths])
    for table in records:
        if len(tables) == max_scenarios:
            more = True
            break
        tables.append(table)
    records.close()
    if not tables:
        return read_womd([]), False
    return pd.concat(tables, ignore_index=True), more


def _add_run_signals(summary: dict[str, Any], chunks: dict[str, list[dict[str, Any]]]
                     ) -> None:
    """Give each recorded-scene episode of a run its traffic signals per step, read again
    from the suite's WOMD files (the run folder keeps the static map only); without the
    files (moved, unreadable) the episodes show no signals and a warning says why."""
    files = _run_womd_files(summary)
    if not files:
        return
    found = _found(files)
    # as the run read them: folders and globs leave out files that are not records
    present = ([str(p) for p in record_files([f for f, paths in found.items() if paths],
                                            note=lambda text: None)]
        if any(found.values()) else [])
    wanted = {str(doc["id"]).rpartition("/")[0] for docs in chunks.values() for doc in docs}
    try:
        roads = _road_maps(present, wanted) if present else {}
    except (TapBenchError, OSError, ValueError) as err:
        warnings.warn(f"the viewer shows no traffic signals: the run's WOMD files could not "
                      f"be read again ({err}).", UserWarning, stacklevel=3)
        return
    gone = [f for f, paths in found.items() if not paths]
    if gone:
        warnings.warn(f"the viewer shows no traffic signals for the scenes of "
                      f"{', '.join(gone)}: the files are "
                      "gone; put them back where the suite names them to see the signals.",
                      UserWarning, stacklevel=3)
    for docs in chunks.values():
        for doc in docs:
            road = roads.get(str(doc["id"]).rpartition("/")[0])
            if road is not None:
                doc["signals"] = signal_field(road.signals)


def _road_maps(paths: Sequence[str | os.PathLike], wanted: set[str]) -> dict[str, Any]:
    """The road maps (with signal states per step) of the scenarios ``wanted``, reading
    the files only until they are all found."""
    found: dict[str, Any] = {}
    maps = iter_road_maps([str(p) for p in paths])
    for road in maps:
        if road.scenario_id in wanted:
            found[road.scenario_id] = road
            if len(found) == len(wanted):
                break
    getattr(maps, "close", lambda: None)()
    return found


def write_womd_viewer(paths: Sequence[str | os.PathLike], output: str | os.PathLike, *,
                      thresholds: Any = "paper", level: str = "maneuver",
                      max_scenarios: int = DEFAULT_VIEW_SCENARIOS) -> Path:
    """Write the replay viewer of WOMD files: each scenario with its map and the label
    timelines of every vehicle (the self-driving car is the ego), the first
    ``max_scenarios`` of the files (read one record at a time, so memory is bounded by
    ``max_scenarios``, not by the files; a warning says when there were more).

    Args:
        paths: WOMD files (Scenario TFRecords, tf.Example TFRecords, ScenarioNet pickles).
        output: the viewer folder.
        thresholds: TAP thresholds (preset name, path or :class:`Thresholds`).
        level: the SDL level of the timelines.
        max_scenarios: the most scenarios shown, at most :data:`MAX_VIEW_SCENARIOS`.

    Returns:
        the path of the viewer's ``index.html``.

    Raises:
        ParameterError: ``max_scenarios`` is not in [1, :data:`MAX_VIEW_SCENARIOS`].
    """
    if (isinstance(max_scenarios, bool) or not isinstance(max_scenarios, int)
            or not 1 <= max_scenarios <= MAX_VIEW_SCENARIOS):
        raise ParameterError("max_scenarios", max_scenarios,
                             f"an integer from 1 to {MAX_VIEW_SCENARIOS}", message=(
                                 f"max_scenarios (--max-scenarios) {max_scenarios!r} must be "
                                 f"an integer from 1 to the limit of {MAX_VIEW_SCENARIOS} "
                                 "(tap_bench.bench.report.viewer.build.MAX_VIEW_SCENARIOS): each "
                                 "scenario costs about 14 MB while the viewer is built."))
    # a README or other non-record file in a folder or glob is left out with a note, as
    # ingest does (a file named on its own is read, and says what is wrong)
    paths = record_files(paths)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        traj, more = _first_scenarios(paths, max_scenarios)
        result = tap(traj, thresholds, source="WOMD")
    if more:
        warnings.warn(f"the viewer shows the first {max_scenarios} scenarios of the files; "
                      "give max_scenarios (--max-scenarios) to show more, up to "
                      f"{MAX_VIEW_SCENARIOS}, or view fewer files.", UserWarning, stacklevel=2)
    sids = list(dict.fromkeys(traj["scenario_id"].astype(str)))
    seed_of = {sid: i for i, sid in enumerate(sids)}
    traj = traj.assign(env="WOMD", policy="logged",
                       seed=traj["scenario_id"].astype(str).map(seed_of).astype("int64"))
    labels = result.labels("all").assign(env="WOMD", policy="logged")
    labels["seed"] = labels["scenario_id"].astype(str).map(seed_of).astype("int64")
    episodes = episode_table(labels=labels, trajectories=traj, level=level,
                             source="WOMD files")
    segments = result.segments(level)
    eps, entries = episode_index(episodes, chunk_by=("scenario_id",), has_replay=sids,
                                 scenes={sid: sid for sid in sids})
    chunks = episode_chunks(traj, eps, segments, labelled_tracks="all")
    maps = read_maps(paths, scenario_ids=set(sids))
    by_map = dict(tuple(maps.groupby("map_id", sort=False))) if len(maps) else {}
    roads = _road_maps(paths, set(sids))
    for docs in chunks.values():
        for doc in docs:
            sub = by_map.get(doc["id"])
            doc["map"] = map_features(sub) if sub is not None else []
            road = roads.get(doc["id"])
            doc["signals"] = signal_field(road.signals) if road is not None else None
    for entry in entries:
        entry["map"] = None  # carried by the episode itself
    index = {"run": {"name": ", ".join(Path(p).name for p in paths), "suite": "WOMD",
                     "level": level, "reference": "", "source": "WOMD", "created": "",
                     "measures": [m.to_dict() for m in MEASURES]},
             "episodes": entries, "maps": {}}
    return write_viewer(output, index, chunks)
