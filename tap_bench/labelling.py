"""TAP end to end: trajectory table in, label, segment and per-step tables out.

>>> result = tap(table, thresholds="paper")          # doctest: +SKIP
>>> result.labels("action")                          # one row per trajectory segment
>>> result.segments("all")                           # one row per run of one label
>>> label(table, level="all")                        # the label table directly
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc

from tap_bench import sdl
from tap_bench.errors import (
    ResampledWarning,
    ShortSegmentWarning,
    TapBenchError,
    TrajectoryTableError,
    did_you_mean,
)
from tap_bench.interactions import (
    OTHER_TYPES,
    RELATIONS,
    InteractionConfig,
    InteractionSteps,
    interaction_steps,
)
from tap_bench.kinematics import Kinematics, Plausibility, compute_kinematics
from tap_bench.labels import GLITCH_COLUMNS, LABEL_COLUMNS, SEGMENT_COLUMNS
from tap_bench.pathframe import LaneMap
from tap_bench.resampling import resample_to_10hz
from tap_bench.stages import StageConfig, StepLabels, find_runs, run_stages
from tap_bench.tableio import EncodedTable
from tap_bench.thresholds import Thresholds, resolve_thresholds
from tap_bench.trajectories import DT, HZ, IDENTIFYING_COLUMNS, validate_and_index

__all__ = ["GLITCH_COLUMNS", "INTERACTION_TRACKS", "LABEL_COLUMNS", "PART_ROWS",
           "SEGMENT_COLUMNS", "TapParts", "TapResult", "label", "tap", "tap_in_parts"]

INTERACTION_TRACKS = ("auto", "ego", "all")
"""Whose interactions :func:`tap` labels: the egos (``is_ego``), every vehicle and cyclist
track, or ``auto``: the egos when the table has an ``is_ego`` column, else every track."""
PART_ROWS = 300_000
"""Rows per part of a large table that :func:`tap_in_parts` labels scenario by scenario:
each part's temporaries (about 300 bytes a row) reuse the memory the part before freed."""

@dataclass(frozen=True)
class TapResult:
    """Everything TAP produced for one trajectory table.

    ``t_end`` is exclusive everywhere: the time of the last step plus 0.1 s, so that the runs
    of one segment tile it and ``t_end - t_start`` is a run's duration.

    Attributes:
        segments_info: one row per labelled valid segment: scenario_id, track_id, segment
            (0-based index of the valid segment within its track), t_start, t_end, n_steps,
            the glitch counts (:data:`GLITCH_COLUMNS`) and the identifying columns of the
            input.
        short_segments: the valid segments shorter than 1 s, which carry no label, with the
            same columns.
        step_labels: per-step codes of every level over the labelled steps.
        step_t: (m,) time of each labelled step [s].
        step_segment: (m,) row of ``segments_info`` of each labelled step.
        step_rows: (m,) row of the validated table of each labelled step.
        kinematics: the kinematic signals and glitch flags of every row.
        thresholds: the thresholds used.
        config: the stage timing parameters used.
        timings: seconds spent per stage (validate, kinematics, stages, tables).
        interactions: per-step relations of the interaction axis (None: not asked for).
        interaction_segments: (k,) rows of ``segments_info`` labelled on that axis, in the
            order their steps are laid end to end in ``interactions``.
        track_ids: (n_tracks,) track id of each track index (names the other agents).
    """

    segments_info: pd.DataFrame
    short_segments: pd.DataFrame
    step_labels: StepLabels
    step_t: np.ndarray
    step_segment: np.ndarray
    step_rows: np.ndarray
    kinematics: Kinematics
    thresholds: Thresholds
    config: StageConfig
    plausibility: Plausibility
    timings: dict[str, float] = field(default_factory=dict, compare=False)
    interactions: InteractionSteps | None = None
    interaction_segments: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    track_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, object))

    def labels(self, level: str = "action") -> pd.DataFrame:
        """The label table (SPEC section 1) at ``level`` or at ``"all"`` levels."""
        levels = sdl.levels(level)
        return _label_table(self.segments_info, levels,
                            [self._sequences(lv, "lateral") for lv in levels],
                            [self._sequences(lv, "longitudinal") for lv in levels],
                            None if self.interactions is None
                            else self._interaction_sequences())

    def segments(self, level: str = "action") -> pd.DataFrame:
        """The segment table (SPEC section 1): one row per run of one label; with
        interactions, the ``axis = "interaction"`` runs too (at every level asked for)."""
        levels = sdl.levels(level)
        runs = []  # (segment, first step, last step, level, axis, labels, other track)
        for lv in levels:
            for axis in sdl.AXES:
                run = self._runs(lv, axis)
                runs.append((run.seg, run.start, run.start + run.length - 1, lv, axis,
                             pa.array(sdl.code_names(lv, axis)).take(pa.array(run.code)),
                             None))
        if self.interactions is not None:
            run, relation, other = self._interaction_runs()
            rows = self._interaction_step_rows()
            names = pa.array(np.asarray(RELATIONS, dtype=object)[relation], pa.string())
            runs += [(self.interaction_segments[run.seg], rows[run.start],
                      rows[run.start + run.length - 1], lv, "interaction", names, other)
                     for lv in levels]
        return self._segment_table(runs)

    def steps(self) -> pd.DataFrame:
        """Per-step labels: scenario_id, track_id, segment, t, one column per level and
        axis (``trace_lateral`` ... ``action_longitudinal``) as categoricals, and the
        per-step flags ``heading_glitch``, ``speed_glitch``, ``heading_trusted`` and
        ``reversing`` (bool)."""
        per_step = self.segments_info.take(self.step_segment).reset_index(drop=True)
        out = pd.DataFrame({
            "scenario_id": per_step["scenario_id"], "track_id": per_step["track_id"],
            "segment": per_step["segment"], "t": self.step_t,
        })
        for level in sdl.LEVELS:
            for axis in sdl.AXES:
                out[f"{level}_{axis}"] = pd.Categorical.from_codes(
                    self.step_labels.codes(level, axis), categories=sdl.code_names(level, axis))
        kin, rows = self.kinematics, self.step_rows
        for name, flags in (("heading_glitch", kin.heading_glitch),
                            ("speed_glitch", kin.speed_glitch),
                            ("heading_trusted", kin.trusted), ("reversing", kin.reversing)):
            out[name] = flags[rows]
        if self.interactions is not None:
            codes = np.full(len(out), -1, np.int64)
            other = np.full(len(out), -1, np.int64)
            rows = self._interaction_step_rows()
            codes[rows] = self.interactions.relation
            other[rows] = self.interactions.other_track
            out["interaction"] = pd.Categorical.from_codes(codes, categories=RELATIONS)
            out["other_track_id"] = self._track_names(other)
        return out

    def glitches(self) -> pd.DataFrame:
        """Per track: its valid segments (labelled and too short), the glitch counts over
        all of them (:data:`GLITCH_COLUMNS`, ``travel`` the largest) and ``still`` (no
        segment gets 1 m from its start, so no turn and no merge)."""
        keys = ["scenario_id", "track_id"]
        every = pd.concat([self.segments_info.assign(labelled=True),
                           self.short_segments.assign(labelled=False)], ignore_index=True)
        if not len(every):
            return pd.DataFrame(columns=[*keys, "segments", "short_segments", "short_steps",
                                         *GLITCH_COLUMNS, "still"])
        labelled = every["labelled"].to_numpy(bool)
        every["short_steps"] = np.where(labelled, 0, every["n_steps"])
        every["short"] = (~labelled).astype(np.int64)
        out = every.groupby(keys, sort=True).agg(
            segments=("segment", "size"), short_segments=("short", "sum"),
            short_steps=("short_steps", "sum"), heading_glitches=("heading_glitches", "sum"),
            speed_glitches=("speed_glitches", "sum"), reversing_steps=("reversing_steps", "sum"),
            travel=("travel", "max")).reset_index()
        out["still"] = out["travel"] < self.plausibility.min_travel
        return out

    # -- the interaction axis -------------------------------------------------------------
    def _interaction_step_rows(self) -> np.ndarray:
        """(m,) positions in the labelled steps of the interaction steps, in their order."""
        seg_first = np.searchsorted(self.step_segment, np.arange(len(self.segments_info)))
        lengths = self.segments_info["n_steps"].to_numpy(np.int64)
        chosen = self.interaction_segments
        n = lengths[chosen]
        return np.repeat(seg_first[chosen], n) + (np.arange(n.sum())
                                                  - np.repeat(np.cumsum(n) - n, n))

    def _track_names(self, track: np.ndarray) -> pd.Series:
        names = np.where(track >= 0, self.track_ids[np.maximum(track, 0)], None)
        return pd.Series(names, dtype=pd.StringDtype("pyarrow", na_value=np.nan))

    def _interaction_runs(self):
        runs = self.interactions.runs
        n_tracks = len(self.track_ids) + 1
        return runs, (runs.code // n_tracks), runs.code % n_tracks - 1

    def _interaction_sequences(self) -> pd.Series:
        """(len(segments_info),) the relations of each segment joined by ' > ', each naming
        its other agent (``"Following (12) > Following (7)"``; NA where the segment is not
        labelled on the interaction axis)."""
        out = np.full(len(self.segments_info), None, dtype=object)
        runs, relation, other = self._interaction_runs()
        tracks = self.track_ids[np.maximum(other, 0)]
        pairs = zip(relation.tolist(), other.tolist(), tracks, strict=True)
        names = np.array([sdl.with_other(RELATIONS[r], str(t) if o >= 0 else None)
                          for r, o, t in pairs], dtype=object)
        bounds = np.searchsorted(runs.seg, np.arange(len(self.interaction_segments) + 1))
        for k, seg in enumerate(self.interaction_segments):
            out[seg] = sdl.SEPARATOR.join(names[bounds[k]:bounds[k + 1]])
        return pd.Series(out, dtype=pd.StringDtype("pyarrow", na_value=np.nan))

    # -- internals -----------------------------------------------------------------------
    @functools.cached_property
    def _seg_first(self) -> np.ndarray:
        """(m,) bool, the first step of each segment (once for every level and axis)."""
        seg_first = np.ones(len(self.step_segment), dtype=bool)
        seg_first[1:] = self.step_segment[1:] != self.step_segment[:-1]
        return seg_first

    def _runs(self, level: str, axis: str):
        return find_runs(self.step_labels.codes(level, axis), self.step_segment,
                         self._seg_first)  # (find_runs writes a copy, not seg_first)

    def _sequences(self, level: str, axis: str) -> pa.Array:
        """(S,) the ' > '-joined label sequence of each segment (a pyarrow string array)."""
        runs = self._runs(level, axis)
        offsets = np.searchsorted(runs.seg, np.arange(len(self.segments_info) + 1))
        tokens = pa.array(sdl.code_names(level, axis)).take(pa.array(runs.code))
        return pc.binary_join(pa.ListArray.from_arrays(pa.array(offsets, pa.int64()), tokens)
                              if len(offsets) else pa.array([], pa.list_(pa.string())),
                              sdl.SEPARATOR)

    def _segment_table(self, runs: list[tuple]) -> pd.DataFrame:
        """The segment table of ``runs`` (each: segment (k,), first and last step rows (k,),
        level, axis, labels (Arrow strings, (k,)), other track (k,) or None), one frame
        built once: the runs of a segment together, in the order given (stable)."""
        info = self.segments_info
        seg = np.concatenate([r[0] for r in runs])
        order = np.argsort(seg, kind="stable")
        counts = [len(r[0]) for r in runs]
        per_run = info[["scenario_id", "track_id", "segment"]
                       + [c for c in info.columns if c in IDENTIFYING_COLUMNS]].take(
            seg[order]).reset_index(drop=True)
        columns: dict[str, object] = {
            "scenario_id": per_run["scenario_id"], "track_id": per_run["track_id"],
            "segment": per_run["segment"],
            "level": _texts(np.repeat(np.asarray([r[3] for r in runs], dtype=object),
                                      counts)[order]),
            "axis": _texts(np.repeat(np.asarray([r[4] for r in runs], dtype=object),
                                     counts)[order]),
            "label": _strings(pa.concat_arrays([r[5] for r in runs]).take(pa.array(order))),
            "t_start": self.step_t[np.concatenate([r[1] for r in runs])[order]],
            "t_end": self.step_t[np.concatenate([r[2] for r in runs])[order]] + DT,
        }
        if self.interactions is not None:
            other = np.concatenate([np.full(len(r[0]), -1, np.int64) if r[6] is None
                                    else r[6] for r in runs])[order]
            columns["other_track_id"] = self._track_names(other)
        for col in per_run.columns[3:]:
            columns[col] = per_run[col]
        return pd.DataFrame(columns)


def _label_table(info: pd.DataFrame, levels: tuple[str, ...], lat: list, lon: list,
                 interaction: pd.Series | None = None) -> pd.DataFrame:
    """The label table (SPEC section 1) at one or more ``levels``, built once: a row per
    segment of ``info`` and level (the levels of a segment together, in the order given),
    its lateral and longitudinal sequences (``lat``, ``lon``: each level's Arrow string
    arrays, (S,)) and, with the interaction axis, its relations."""
    n, k = len(info), len(levels)

    def joined(sequences: list) -> pa.Array | pa.ChunkedArray:
        if k == 1:
            return sequences[0]
        chunks = [c for a in sequences
                  for c in (a.chunks if isinstance(a, pa.ChunkedArray) else [a])]
        order = pa.array((np.arange(k)[None, :] * n + np.arange(n)[:, None]).ravel())
        return pa.chunked_array(chunks, type=pa.string()).take(order)

    lateral, longitudinal = joined(lat), joined(lon)
    sdl_text = pc.binary_join_element_wise(lateral, longitudinal, sdl.SDL_SEPARATOR)
    rows = np.repeat(np.arange(n), k)
    per_row = info if k == 1 else info.take(rows).reset_index(drop=True)
    columns: dict[str, object] = {
        "scenario_id": per_row["scenario_id"], "track_id": per_row["track_id"],
        "segment": per_row["segment"],
        "level": _texts(np.tile(np.asarray(levels, dtype=object), n)),
        "lateral": _strings(lateral), "longitudinal": _strings(longitudinal),
        "sdl": _strings(sdl_text),
    }
    if interaction is not None:
        columns["interaction"] = (interaction if k == 1
                                  else interaction.take(rows).reset_index(drop=True))
    columns.update(t_start=per_row["t_start"], t_end=per_row["t_end"])
    for col in (*GLITCH_COLUMNS, *IDENTIFYING_COLUMNS):
        if col in info.columns:
            columns[col] = per_row[col]
    return pd.DataFrame(columns)


_TEXT = pd.Series(["level"]).dtype
"""The dtype pandas gives a column of one string broadcast (``"level": "trace"``)."""


def _texts(values: np.ndarray) -> pd.api.extensions.ExtensionArray:
    """(n,) Python strings as a column of :data:`_TEXT` (an empty one too)."""
    return pd.array(values, dtype=_TEXT)


def _strings(values: pa.Array) -> pd.Series:
    """A pyarrow string array as a pandas string Series, without a round trip via Python."""
    return pd.Series(values, dtype=pd.StringDtype("pyarrow", na_value=np.nan))


def _segment_frame(tracks: dict, kin: Kinematics, index, which: np.ndarray,
                   ordinal: np.ndarray) -> pd.DataFrame:
    """One row per valid segment selected by ``which`` (bool, (n_segments,)); ``tracks``:
    :meth:`~tap_bench.trajectories.CheckedTable.per_track_arrays`."""
    rows = index.segment_start[which]
    stops = index.segment_stop[which]
    # each track's columns at its segments, as arrays (a frame of arrays needs no index
    # alignment; the columns keep their types)
    of_track = index.segment_track[which]
    if len(of_track) == index.n_tracks and (of_track == np.arange(len(of_track))).all():
        per_track = tracks  # one segment per track: the columns as they are
    elif not len(of_track):
        per_track = {c: v[:0] for c, v in tracks.items()}
    else:
        per_track = {c: (v[of_track] if isinstance(v, np.ndarray) else v.take(of_track))
                     for c, v in tracks.items()}
    names = list(per_track)
    columns: dict[str, object] = {c: per_track[c] for c in names[:2]}
    columns.update(segment=ordinal[which], t_start=kin.t[rows],
                   t_end=kin.t[stops - 1] + DT if len(rows) else np.zeros(0),
                   n_steps=stops - rows)
    counts = {"heading_glitches": kin.heading_glitch, "speed_glitches": kin.speed_glitch,
              "reversing_steps": kin.reversing}
    for name, flags in counts.items():
        flagged = index.segment[np.flatnonzero(flags)]  # flags are rare: count them sparsely
        per_segment = np.bincount(flagged, minlength=index.n_segments)
        columns[name] = per_segment[which].astype(np.int64)
    columns["travel"] = kin.travel[which]
    columns.update({c: per_track[c] for c in names[2:]})
    return pd.DataFrame(columns)


def tap(table: pd.DataFrame, thresholds: Thresholds | str = "paper",
        config: StageConfig | None = None, *, plausibility: Plausibility | None = None,
        source: str = "trajectory table", interactions: str | None = None,
        interaction_config: InteractionConfig | None = None,
        map_table: pd.DataFrame | LaneMap | None = None) -> TapResult:
    """Run the Trajectory-to-Action Pipeline on a trajectory table.

    Args:
        table: a trajectory table (SPEC section 1), validated on entry.
        thresholds: a :class:`Thresholds`, a preset name (``"paper"``) or a JSON file path.
        config: stage parameters (1 s minimum run, the merge rule's 4 s, 0.2 rad, 1.5 m).
        plausibility: the bounds that tell glitches from motion (SPEC section 2).
        source: a name for the table in error messages (its file path).
        interactions: also label the interaction axis (SPEC 7,
            :mod:`tap_bench.interactions`) of the egos (``"ego"``: tracks with ``is_ego``),
            of every vehicle and cyclist track (``"all"``), or ``"auto"`` (the egos when
            the table has ``is_ego``, else every track); None: not at all.
        interaction_config: parameters of the interaction axis.
        map_table: lane centre lines (:mod:`tap_bench.maps`) along which an ego's path goes
            on beyond its record (interaction axis), or a
            :class:`~tap_bench.pathframe.LaneMap` made of them that the measures' call
            shares (:meth:`~tap_bench.pathframe.LaneMap.of_maps`); None: an arc of its last
            curvature.

    Returns:
        A :class:`TapResult`; segments shorter than 1 s are listed in ``short_segments``.
    """
    if interactions is not None and interactions not in INTERACTION_TRACKS:
        raise did_you_mean("interactions", str(interactions), INTERACTION_TRACKS)
    config = config or StageConfig()
    plausibility = plausibility or Plausibility()
    th = resolve_thresholds(thresholds)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    checked = _validated_at_10hz(table, source)
    index = checked.index
    t1 = time.perf_counter()
    kin = compute_kinematics(checked, plausibility)
    t2 = time.perf_counter()

    lengths = index.segment_length
    track_first_seg = np.searchsorted(index.segment_track, np.arange(index.n_tracks))
    ordinal = np.arange(index.n_segments) - track_first_seg[index.segment_track]
    long_enough = lengths >= config.min_steps
    starts, stops = index.segment_start[long_enough], index.segment_stop[long_enough]
    tracks = checked.per_track_arrays(["scenario_id", "track_id", *IDENTIFYING_COLUMNS])
    # (no segment of one kind: that frame is the other's first none of its rows, the
    # same columns, without building a frame again)
    if long_enough.all():
        info = _segment_frame(tracks, kin, index, long_enough, ordinal)
        short = info.iloc[:0]
    elif not long_enough.any():
        short = _segment_frame(tracks, kin, index, ~long_enough, ordinal)
        info = short.iloc[:0]
    else:
        info = _segment_frame(tracks, kin, index, long_enough, ordinal)
        short = _segment_frame(tracks, kin, index, ~long_enough, ordinal)

    seg_len = stops - starts
    n_steps = int(seg_len.sum())
    step_segment = np.repeat(np.arange(len(starts)), seg_len)
    if n_steps == len(kin.t):  # every row labelled (the segments tile the table): the
        # steps are the rows, and the signals are given as they are
        step_rows = np.arange(n_steps)
        w, a, v, reversing = kin.w, kin.a, kin.v, kin.reversing
    else:
        step_rows = np.repeat(starts, seg_len) + (
            np.arange(n_steps) - np.repeat(np.cumsum(seg_len) - seg_len, seg_len))
        w, a, v = kin.w[step_rows], kin.a[step_rows], kin.v[step_rows]
        reversing = kin.reversing[step_rows]
    t3 = time.perf_counter()
    labels = run_stages(w, a, v, seg_len, th, config, heading=kin.heading, x=kin.x, y=kin.y,
                        rows=step_rows, reversing=reversing)
    t4 = time.perf_counter()
    timings.update(validate=t1 - t0, kinematics=t2 - t1, layout=t3 - t2, stages=t4 - t3)
    extra = {}
    if interactions is not None:
        if interactions == "auto":
            interactions = "ego" if "is_ego" in info.columns else "all"
        chosen = _interaction_segments(info, interactions, source)
        lateral = np.full(len(kin.t), -1, np.int8)  # every labelled row's lateral code
        lateral[step_rows] = labels.maneuver_lateral
        inter = interaction_steps(checked, kin, starts[chosen], stops[chosen], lateral,
                                  th.a_dec, interaction_config, map_table=map_table)
        track_ids = np.asarray(pd.Series(tracks["track_id"]).to_numpy(object), dtype=object)
        extra = {"interactions": inter, "interaction_segments": chosen,
                 "track_ids": track_ids}
        timings["interactions"] = time.perf_counter() - t4
    return TapResult(segments_info=info, short_segments=short, step_labels=labels,
                     step_t=kin.t[step_rows], step_segment=step_segment, step_rows=step_rows,
                     kinematics=kin,
                     thresholds=th, config=config, plausibility=plausibility,
                     timings=timings, **extra)


@dataclass(frozen=True)
class TapParts:
    """The tables of :class:`TapResult` for a table labelled in parts (whole scenarios, in
    the order of the validated table, :func:`tap_in_parts`): each the parts' tables laid
    end to end, equal to one :func:`tap` call's.

    Attributes:
        parts: the result of each part, in order. Their kinematics keep the per-row flags
            and the track index that the tables need; the signals (``t``, ``v``, ``a``,
            ``w``, ``heading``, ``x``, ``y``) are left out (empty) to bound the memory.
        per_step: the parts keep the per-step times and rows and the per-row flags and
            track index that :meth:`segments` and :meth:`steps` read (False: left out,
            and those two raise).
    """

    parts: tuple[TapResult, ...]
    per_step: bool = True

    def labels(self, level: str = "action") -> pd.DataFrame:
        """:meth:`TapResult.labels` of the whole table: without the interaction axis, one
        frame a level of the parts' label sequences laid end to end (not one a part)."""
        if len(self.parts) == 1 or self.interactions is not None:
            return self._joined([p.labels(level) for p in self.parts])
        info = self.segments_info

        def sequences(lv: str, axis: str) -> pa.ChunkedArray:
            return pa.chunked_array([p._sequences(lv, axis) for p in self.parts],
                                    type=pa.string())

        levels = sdl.levels(level)
        return _label_table(info, levels, [sequences(lv, "lateral") for lv in levels],
                            [sequences(lv, "longitudinal") for lv in levels])

    def segments(self, level: str = "action") -> pd.DataFrame:
        """:meth:`TapResult.segments` of the whole table."""
        self._need_steps("segments")
        return self._joined([p.segments(level) for p in self.parts])

    def steps(self) -> pd.DataFrame:
        """:meth:`TapResult.steps` of the whole table."""
        self._need_steps("steps")
        return self._joined([p.steps() for p in self.parts])

    def _need_steps(self, table: str) -> None:
        if not self.per_step:
            raise TapBenchError(f"the {table} table reads the per-step times and rows, which "
                                "this table's parts did not keep: label it with "
                                "tap_in_parts(..., per_step=True).")

    def glitches(self) -> pd.DataFrame:
        """:meth:`TapResult.glitches` of the whole table (of the joined segment tables: one
        grouping instead of one a part)."""
        if len(self.parts) == 1:
            return self.parts[0].glitches()
        return dataclasses.replace(self.parts[0], segments_info=self.segments_info,
                                   short_segments=self.short_segments).glitches()

    @property
    def segments_info(self) -> pd.DataFrame:
        return self._joined([p.segments_info for p in self.parts])

    @property
    def short_segments(self) -> pd.DataFrame:
        return self._joined([p.short_segments for p in self.parts])

    @property
    def interactions(self) -> InteractionSteps | None:
        """The first part's interaction steps (None: the interaction axis was not asked
        for); :attr:`interaction_segments` counts every part's."""
        return self.parts[0].interactions

    @property
    def interaction_segments(self) -> np.ndarray:
        """(k,) rows of :attr:`segments_info` labelled on the interaction axis."""
        offsets = np.cumsum([0] + [len(p.segments_info) for p in self.parts[:-1]])
        return np.concatenate([p.interaction_segments + o
                               for p, o in zip(self.parts, offsets, strict=True)])

    @property
    def timings(self) -> dict[str, float]:
        """Seconds per stage, summed over the parts."""
        out: dict[str, float] = {}
        for part in self.parts:
            for name, seconds in part.timings.items():
                out[name] = out.get(name, 0.0) + seconds
        return out

    @staticmethod
    def _joined(frames: list[pd.DataFrame]) -> pd.DataFrame:
        # parts without rows add none (an empty frame's columns may have other dtypes)
        kept = [f for f in frames if len(f)] or frames[:1]
        if len(kept) == 1:
            return kept[0]
        return pd.concat(kept, ignore_index=True)


def tap_in_parts(table: pd.DataFrame | EncodedTable, thresholds: Thresholds | str = "paper",
                 config: StageConfig | None = None, *, part_rows: int = PART_ROWS,
                 per_step: bool = True, **options) -> TapParts:
    """:func:`tap` of a large table, whole scenarios at a time: the same tables, with the
    memory of one part's temporaries instead of the whole table's (the command line's
    labelling of 25,900 trajectories peaked at 1.1 GB, and the kernel's page faults cost
    as much CPU as the labelling).

    A table is cut only where it can be without changing a result: its ``scenario_id`` is
    a string column whose scenarios each lie in one run of rows, in the order the
    validated table sorts them (TAP labels each scenario on its own, and each one-second
    block's position mean sums its own scenario's rows only), cut between scenarios every
    ``part_rows`` rows or so. Otherwise, and when any part raises an error or a warning,
    the whole table is labelled in one call, which gives that error or warning as
    :func:`tap` does (the row numbers of the whole table).

    Args:
        table: a trajectory table (SPEC section 1), or a Parquet file of one read with its
            strings encoded (:func:`tap_bench.tableio.read_table_encoded`): its parts are
            labelled with their string columns as categoricals of values sorted as the
            strings sort (so the tracks' order is the strings'), and the tables give those
            columns back as the strings :func:`~tap_bench.tableio.read_table` reads, equal
            to the tables of ``tap(table.frame())``.
        thresholds, config: as :func:`tap`.
        part_rows: rows per part (about; a scenario is never split).
        per_step: keep what the segment and per-step tables need (False: the parts drop
            the per-step times and rows, the per-row flags and track index as they are
            labelled, about 36 bytes a row; ``segments()`` and ``steps()`` then raise).
        **options: the keyword arguments of :func:`tap`.
    """
    encoded = isinstance(table, EncodedTable)
    bounds = _scenario_parts(table, part_rows)
    if bounds is None:
        return TapParts((tap(table.frame() if encoded else table, thresholds, config,
                             **options),))
    thresholds = resolve_thresholds(thresholds)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            parts = tuple(
                _without_signals(_decoded(tap(table.part(a, b), thresholds, config,
                                              **options), table)
                                 if encoded else tap(table.iloc[a:b], thresholds, config,
                                                     **options), per_step)
                for a, b in itertools.pairwise(bounds))
    except Exception:  # any error: the whole table's call gives it as tap() does
        caught = [None]
    if caught:
        return TapParts((tap(table.frame() if encoded else table, thresholds, config,
                             **options),))
    return TapParts(parts, per_step)


def _without_signals(result: TapResult, per_step: bool = True) -> TapResult:
    """``result`` without the per-row signals of its kinematics (see :class:`TapParts`);
    not ``per_step``: without the per-step times and rows, the per-row flags and track
    index either."""
    empty = np.zeros(0)
    kin = dataclasses.replace(result.kinematics, t=empty, v=empty, a=empty, w=empty,
                              heading=empty, x=empty, y=empty)
    if per_step:
        return dataclasses.replace(result, kinematics=kin)
    none, flags = np.zeros(0, np.int64), np.zeros(0, bool)
    kin = dataclasses.replace(kin, speed_glitch=flags, heading_glitch=flags, trusted=flags,
                              reversing=flags,
                              index=dataclasses.replace(kin.index, track=none, segment=none))
    return dataclasses.replace(result, kinematics=kin, step_t=empty, step_rows=none)


def _decoded(result: TapResult, table: EncodedTable) -> TapResult:
    """``result`` of a part of ``table`` with its segment tables' encoded columns (the
    categoricals :meth:`EncodedTable.part` made) as the strings they stand for."""

    def strings(frame: pd.DataFrame) -> pd.DataFrame:
        names = [c for c in frame.columns if c in table.codes
                 and isinstance(frame[c].dtype, pd.CategoricalDtype)]
        if not names:
            return frame
        frame = frame.copy()
        for name in names:
            frame[name] = table.decoded(name, frame[name].array.codes)
        return frame

    return dataclasses.replace(result, segments_info=strings(result.segments_info),
                               short_segments=strings(result.short_segments))


def _scenario_parts(table: pd.DataFrame | EncodedTable, part_rows: int) -> list[int] | None:
    """Row bounds of the parts of :func:`tap_in_parts` (first row of each part, then the
    number of rows), or None when the table is not to be cut."""
    if isinstance(table, EncodedTable):
        # codes rank the strings: a run starts where the code changes, and the runs are in
        # the strings' order when their codes increase
        n = table.num_rows
        codes = table.codes.get("scenario_id")
        if n <= part_rows or codes is None or (codes < 0).any():
            return None
        change = np.ones(n, dtype=bool)
        change[1:] = codes[1:] != codes[:-1]
        starts = np.flatnonzero(change)
        if not (np.diff(codes[starts]) > 0).all():
            return None
    else:
        if (not isinstance(table, pd.DataFrame) or len(table) <= part_rows or
                "scenario_id" not in table.columns):
            return None
        n = len(table)
        column = table["scenario_id"]
        if not isinstance(column.dtype, pd.StringDtype) or column.hasnans:
            return None
        values = column.array
        change = np.ones(n, dtype=bool)
        change[1:] = np.asarray(values[1:] != values[:-1], dtype=bool)
        starts = np.flatnonzero(change)
        names = values.take(starts).tolist()
        # each scenario one run, the runs in the validated order (code points, as Arrow
        # sorts)
        if not all(a < b for a, b in itertools.pairwise(names)):
            return None
    bounds = [0]
    for start in starts[1:].tolist():
        if start - bounds[-1] >= part_rows:
            bounds.append(start)
    bounds.append(n)
    return bounds if len(bounds) > 2 else None


def _validated_at_10hz(table: pd.DataFrame, source: str):
    """The validated table; one sampled faster than 10 Hz (nuPlan 20 Hz, highD 25 Hz) is
    resampled to 10 Hz first, with a :class:`~tap_bench.errors.ResampledWarning` (SPEC 4.7:
    positions, heading and speed interpolated onto the multiples of 0.1 s, then the yaw
    rate and acceleration derived at 10 Hz). Slower input is refused with the fix."""
    try:
        return validate_and_index(table, source=source)
    except TrajectoryTableError as err:
        if err.rate_hz is None or err.rate_hz <= HZ:
            raise
        rate = err.rate_hz
    resampled = resample_to_10hz(table, source=source, align=True)
    warnings.warn(f"{source}: sampled at {rate:.3g} Hz; resampled to 10 Hz on entry (linear "
                  "interpolation of x, y, speed and unwrapped heading onto the multiples of "
                  f"0.1 s; {len(table)} rows became {len(resampled)}).", ResampledWarning,
                  stacklevel=3)
    return validate_and_index(resampled, source=source)


def _interaction_segments(info: pd.DataFrame, tracks: str, source: str) -> np.ndarray:
    """Rows of ``info`` (labelled segments) whose track is labelled on the interaction axis."""
    if tracks == "ego":
        if "is_ego" not in info.columns:
            raise TapBenchError(
                f"{source}: interactions='ego' labels the tracks marked by an is_ego column, "
                "and the table has none; mark the ego, or use interactions='all' (every "
                "vehicle and cyclist).")
        is_ego = info["is_ego"]
        # validated: numpy bools, nothing missing (other types as before)
        mask = (is_ego.to_numpy() if is_ego.dtype == np.bool_ else
            is_ego.fillna(False).to_numpy(bool))
    else:
        mask = np.ones(len(info), bool)
    if "object_type" in info.columns:  # as astype(str).isin: a missing type is no type
        kinds = info["object_type"].to_numpy(object)
        mask = mask & np.fromiter((isinstance(k, str) and k in OTHER_TYPES for k in kinds),
                                  bool, len(kinds))
    return np.flatnonzero(mask)


def label(table: pd.DataFrame, thresholds: Thresholds | str = "paper", level: str = "action",
          config: StageConfig | None = None, *, plausibility: Plausibility | None = None,
          source: str = "trajectory table") -> pd.DataFrame:
    """The SDL label table of a trajectory table (one row per trajectory segment and level).

    Args:
        table: a trajectory table (SPEC section 1).
        thresholds: a :class:`Thresholds`, a preset name (``"paper"``) or a JSON file path.
        level: ``"trace"``, ``"trend"``, ``"maneuver"``, ``"action"`` or ``"all"``.
        config: stage parameters.
        plausibility: the bounds that tell glitches from motion (SPEC section 2).
        source: a name for the table in error messages.

    Warns:
        ShortSegmentWarning: when valid segments shorter than 1 s had to be left unlabelled
            (use :func:`tap` to get them as a table).
    """
    sdl.levels(level)  # fail on a bad level before doing any work
    result = tap(table, thresholds, config, plausibility=plausibility, source=source)
    warn_short_segments(result)
    return result.labels(level)


def warn_short_segments(result: TapResult) -> None:
    """Warn, with counts, when some valid segments were too short to label."""
    short = result.short_segments
    if len(short):
        n_tracks = short[["scenario_id", "track_id"]].drop_duplicates().shape[0]
        warnings.warn(
            f"{len(short)} valid segment(s) in {n_tracks} track(s) are shorter than "
            f"{result.config.min_run:g} s and carry no label (steps: "
            f"{int(short['n_steps'].sum())}); tap(...).short_segments lists them.",
            ShortSegmentWarning, stacklevel=3)
