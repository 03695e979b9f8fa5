"""What the replay viewer shows, as compact JSON-ready documents.

Tables in (episode, trajectory, segment and map tables), documents out:

- the **index**: one small record per episode (env, policy, seed, name, crash, labels, novelty,
  measures) for the filterable list, the road maps shared by the episodes of an env, and the
  run's facts;
- the **chunks**: the episodes themselves, grouped so that the episodes a person compares
  (every policy on one env and seed) load together.

Positions are quantised to :data:`POSITION_STEP` (0.1 m; finer when a scene is wider than
int16 allows), headings to 2 pi / 65536, and both are stored as base64 int16 arrays, about
8 bytes per vehicle per step. Speeds and the ego's safety measures (gap, headway, TTC) are
int16 too, in hundredths. Label timelines are ``[t_start, t_end, label]`` runs.
"""

from __future__ import annotations

import base64
import hashlib
import itertools
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import pandas as pd

from tap_bench.bench.measures import MEASURES, VEHICLE_LENGTH, ego_step_measures
from tap_bench.errors import TrajectoryTableError
from tap_bench.trajectories import HZ

__all__ = ["MISSING", "POSITION_STEP", "clip_polyline", "encode_int16", "episode_chunks",
           "episode_index", "episode_name", "map_features", "signal_field", "SIGNAL_COLOURS"]

POSITION_STEP = 0.1  # [m] quantisation of positions: a 50th of a car's length
VEHICLE_WIDTH = 2.0  # [m] highway-env's vehicle width; WOMD tracks carry their own
MISSING = -32768
"""The int16 code of a missing value (an invalid step, no leader)."""
MAP_MARGIN = 40.0  # [m] road drawn beyond the farthest vehicle of an env
_TYPE_CODES = {"vehicle": "v", "pedestrian": "p", "cyclist": "c", "other": "o"}
_MEASURE_FIELDS = (("speed", "speed"), ("gap", "gap_m"), ("headway", "headway_s"),
                   ("ttc", "ttc_s"))


def encode_int16(values: np.ndarray) -> str:
    """(n,) int-valued array as base64 of little-endian int16 (what the viewer decodes)."""
    return base64.b64encode(np.asarray(values, dtype="<i2").tobytes()).decode("ascii")


def _quantise(values: np.ndarray, step: float) -> np.ndarray:
    """Values [unit] to int16 multiples of ``step``; NaN to :data:`MISSING`."""
    q = np.round(values / step)
    q = np.where(np.isfinite(q), np.clip(q, -32767, 32767), MISSING)
    return q.astype(np.int16)


def clip_polyline(xy: np.ndarray, box: tuple[float, float, float, float]) -> list[np.ndarray]:
    """The pieces of a polyline inside an axis-aligned box (Liang-Barsky on each segment).

    Args:
        xy: (n, 2) points [m].
        box: (x_min, y_min, x_max, y_max) [m].

    Returns:
        the polylines (k_i, 2) inside the box, in order.
    """
    x0, y0, x1, y1 = box
    pieces: list[list[np.ndarray]] = []
    current: list[np.ndarray] = []
    for a, b in itertools.pairwise(xy):
        d = b - a
        t_lo, t_hi = 0.0, 1.0
        inside = True
        for p, q in ((-d[0], a[0] - x0), (d[0], x1 - a[0]), (-d[1], a[1] - y0),
                     (d[1], y1 - a[1])):
            if p == 0:
                if q < 0:
                    inside = False
                    break
                continue
            r = q / p
            if p < 0:
                t_lo = max(t_lo, r)
            else:
                t_hi = min(t_hi, r)
        if not inside or t_lo > t_hi:
            if current:
                pieces.append(current)
                current = []
            continue
        start, end = a + t_lo * d, a + t_hi * d
        if not current:
            current = [start]
        elif np.any(np.abs(current[-1] - start) > 1e-9):
            pieces.append(current)
            current = [start]
        current.append(end)
        if t_hi < 1.0:
            pieces.append(current)
            current = []
    if current:
        pieces.append(current)
    return [np.array(p) for p in pieces if len(p) >= 2]


def map_features(roads: pd.DataFrame, box: tuple[float, float, float, float] | None = None
                 ) -> list[list[Any]]:
    """A map table (one ``map_id``) as the viewer's features, clipped to ``box``.

    Returns:
        ``[kind, style, width or null, [x0, y0, x1, y1, ...]]`` per piece, coordinates in
        metres rounded to 0.1 m, lanes first.
    """
    out: list[list[Any]] = []
    order = {"lane": 0, "road_line": 1, "road_edge": 2, "crosswalk": 3}
    groups = sorted(roads.groupby("feature_id", sort=False),
                    key=lambda g: (order.get(g[1]["kind"].iloc[0], 9), g[0]))
    for _, feat in groups:
        xy = feat[["x", "y"]].to_numpy(float)
        width = feat["width"].iloc[0]
        pieces = [xy] if box is None else clip_polyline(xy, box)
        for piece in pieces:
            out.append([feat["kind"].iloc[0], feat["style"].iloc[0] or "",
                        None if not np.isfinite(width) else round(float(width), 2),
                        np.round(piece.ravel(), 1).tolist()])
    return out


def _segments_by_track(segments: pd.DataFrame | None) -> dict[tuple[str, str], list]:
    if segments is None or segments.empty:
        return {}
    out: dict[tuple[str, str], dict[str, list]] = {}
    has_other = "other_track_id" in segments.columns
    cols = ["scenario_id", "track_id", "axis", "label", "t_start", "t_end"]
    for row in segments[cols + (["other_track_id"] if has_other else [])].itertuples(
            index=False):
        entry = [round(float(row.t_start), 2), round(float(row.t_end), 2), str(row.label)]
        other = getattr(row, "other_track_id", None) if has_other else None
        if other is not None and not pd.isna(other) and str(other):
            entry.append(str(other))
        out.setdefault((str(row.scenario_id), str(row.track_id)), {}).setdefault(
            str(row.axis), []).append(entry)
    return out


def _track_record(cols: Mapping[str, np.ndarray], rows: np.ndarray, step0: int,
                  origin: np.ndarray, step: float, is_ego: bool) -> dict[str, Any]:
    """One track (the table's ``rows`` of it, in time order) as the viewer's record."""
    steps = np.rint(cols["t"][rows] * HZ).astype(np.int64) - step0
    first = int(steps.min())
    n = int(steps.max()) - first + 1
    x = np.full(n, np.nan)
    y = np.full(n, np.nan)
    h = np.full(n, np.nan)
    valid = cols["valid"][rows] if "valid" in cols else np.ones(len(rows), bool)
    idx = steps[valid] - first
    kept = rows[valid]
    x[idx] = cols["x"][kept] - origin[0]
    y[idx] = cols["y"][kept] - origin[1]
    h[idx] = cols["heading"][kept]
    h = np.mod(h + np.pi, 2 * np.pi) - np.pi
    qx = _quantise(x, step)
    qy = _quantise(y, step)
    qh = _quantise(h, np.pi / 32767)
    qh[qx == MISSING] = MISSING
    size = {"length": VEHICLE_LENGTH, "width": VEHICLE_WIDTH}
    for col in size:
        if col in cols:
            v = cols[col][kept]
            v = v[np.isfinite(v) & (v > 0)]
            if len(v):
                size[col] = float(np.median(v))
    kind = (str(cols["object_type"][rows[0]]) if "object_type" in cols and len(rows)
        else "vehicle")
    return {"id": str(cols["track_id"][rows[0]]), "ego": bool(is_ego),
            "type": _TYPE_CODES.get(kind, "o"), "len": round(size["length"], 2),
            "wid": round(size["width"], 2), "s0": first, "n": n,
            "xyh": encode_int16(np.concatenate([qx, qy, qh]))}


def _episode_record(sid: str, cols: Mapping[str, np.ndarray], tracks: list[np.ndarray],
                    steps: Mapping[str, np.ndarray] | None,
                    segs: Mapping[tuple[str, str], Mapping[str, list]],
                    labelled_tracks: str) -> dict[str, Any]:
    """One episode (scenario) as the viewer's document: ``tracks`` are the rows of each of
    its tracks in the table's columns ``cols``, in order of first appearance."""
    rows = np.concatenate(tracks)
    t = cols["t"][rows]
    step0 = int(np.rint(t.min() * HZ))
    x, y = cols["x"][rows], cols["y"][rows]
    valid = np.isfinite(x) & np.isfinite(y)
    if "valid" in cols:
        valid &= cols["valid"][rows]
    if not valid.any():
        raise TrajectoryTableError(f"scenario {sid!r} has no valid position to show.",
                                   column="valid")
    xs, ys = x[valid], y[valid]
    lo = np.array([xs.min(), ys.min()])
    hi = np.array([xs.max(), ys.max()])
    origin = np.round((lo + hi) / 2, 1)
    step = max(POSITION_STEP, float(np.max(hi - lo)) / 2 / 32000)
    is_ego = cols["is_ego"][rows] if "is_ego" in cols else np.zeros(len(rows), bool)
    ego_ids = {str(v) for v in cols["track_id"][rows[is_ego]]}
    records = []
    labels: dict[str, Any] = {}
    for track in tracks:
        tid = str(cols["track_id"][track[0]])
        ego = tid in ego_ids
        records.append(_track_record(cols, track, step0, origin, step, ego))
        if (ego or labelled_tracks == "all") and (sid, tid) in segs:
            labels[tid] = segs[(sid, tid)]
    records.sort(key=lambda r: not r["ego"])  # the ego first
    doc: dict[str, Any] = {
        "id": sid, "t0": round(step0 / HZ, 2), "n": int(np.rint(t.max() * HZ)) - step0 + 1,
        "origin": origin.tolist(), "q": step, "tracks": records, "labels": labels,
        "crash_t": None}
    if "crashed" in cols and ego_ids:
        crashed = cols["crashed"][rows] & is_ego
        if crashed.any():
            doc["crash_t"] = round(float(t[crashed].min()), 2)
    if steps is not None and len(steps["t"]):
        s = np.rint(steps["t"] * HZ).astype(np.int64) - step0
        first, n = int(s.min()), int(s.max() - s.min() + 1)
        measures = {"s0": first, "n": n}
        for key, col in _MEASURE_FIELDS:
            v = np.full(n, np.nan)
            v[s - first] = steps[col]
            measures[key] = encode_int16(_quantise(v, 0.01))
        scored = steps["t"][steps["scored"]]
        measures["scored_from"] = round(float(scored.min()), 2) if len(scored) else None
        doc["measures"] = measures
    return doc


def _columns(table: pd.DataFrame) -> dict[str, np.ndarray]:
    """The columns the viewer reads, as numpy arrays (flags with missing as False)."""
    cols: dict[str, np.ndarray] = {}
    for col in ("t", "x", "y", "heading", "length", "width"):
        if col in table.columns:
            cols[col] = table[col].to_numpy(float)
    for col in ("valid", "is_ego", "crashed"):
        if col in table.columns:
            cols[col] = table[col].fillna(False).to_numpy(bool)
    for col in ("track_id", "object_type"):
        if col in table.columns:
            cols[col] = table[col].to_numpy(object)
    return cols


def _groups(keys: pd.Series) -> list[np.ndarray]:
    """The rows of each value of ``keys``, values in order of first appearance, each
    group's rows in table order (what ``groupby(sort=False)`` gives)."""
    codes, _ = pd.factorize(keys, sort=False)
    order = np.argsort(codes, kind="stable")
    bounds = np.flatnonzero(np.diff(codes[order])) + 1
    return np.split(order, bounds) if len(order) else []


SIGNAL_COLOURS = "urygrygry"
"""Signal state number (:data:`tap_bench.womd.roadmap.LANE_STATES`) -> the viewer's code:
u unknown, r red (stop, arrow stop, flashing stop), y yellow (caution), g green (go)."""


def signal_field(signals: Any) -> dict[str, Any] | None:
    """A scene's traffic signals as the viewer draws them: one stop point per controlled
    lane, its state per step as a letter.

    Args:
        signals: :class:`tap_bench.womd.roadmap.SignalStates` (steps x lanes).

    Returns:
        ``{"lanes": [lane id], "points": [[x, y]] [m], "states": [str per step]}`` where
        character j of a step's string is lane j's state (:data:`SIGNAL_COLOURS`: r, y, g,
        u); None when the scene has no signals.
    """
    state = np.asarray(signals.state)
    if state.ndim != 2 or not state.shape[1]:
        return None
    codes = np.array(list(SIGNAL_COLOURS))[np.clip(state, 0, len(SIGNAL_COLOURS) - 1)]
    return {"lanes": [int(i) for i in signals.lane],
            "points": np.round(np.asarray(signals.stop_point, float), 2).tolist(),
            "states": ["".join(row) for row in codes]}


def episode_chunks(trajectories: pd.DataFrame, episodes: pd.DataFrame,
                   segments: pd.DataFrame | None, *, labelled_tracks: str = "ego"
                   ) -> dict[str, list[dict[str, Any]]]:
    """The episodes of a trajectory table as the viewer's documents, grouped in chunks.

    Args:
        trajectories: trajectory table (SPEC section 1) with ``is_ego``.
        episodes: the episode table; its ``scenario_id`` and ``chunk`` columns say which
            chunk each scenario goes to (see :func:`episode_index`).
        segments: the segment table (label timelines); None shows no timelines.
        labelled_tracks: ``"ego"`` (the policy's vehicle) or ``"all"``: whose timelines go in.

    Returns:
        chunk name -> list of episode documents.
    """
    chunk_of = dict(zip(episodes["scenario_id"].astype(str), episodes["chunk"], strict=True))
    steps_by: dict[str, dict[str, np.ndarray]] = {}
    if "is_ego" in trajectories.columns:
        steps = ego_step_measures(trajectories)
        fields = {"t": steps["t"].to_numpy(float), "scored": steps["scored"].to_numpy(bool),
                  **{col: steps[col].to_numpy(float) for _, col in _MEASURE_FIELDS}}
        sids = steps["scenario_id"].to_numpy(object)
        for rows in _groups(steps["scenario_id"]):
            steps_by[str(sids[rows[0]])] = {k: v[rows] for k, v in fields.items()}
    segs = _segments_by_track(segments)
    cols = _columns(trajectories)
    scenario = trajectories["scenario_id"]
    # rows by (scenario, track): scenarios, and tracks within each, in order of first
    # appearance, rows in table order
    pair = (pd.Series(scenario.astype(str).to_numpy(object)) + "\x00" +
        trajectories["track_id"].astype(str).to_numpy(object))
    tracks = _groups(pair)
    scenario_of = scenario.to_numpy(object)
    by_scenario: dict[str, list[np.ndarray]] = {}
    for rows in tracks:
        by_scenario.setdefault(str(scenario_of[rows[0]]), []).append(rows)
    chunks: dict[str, list[dict[str, Any]]] = {}
    for sid, scenario_tracks in by_scenario.items():
        if sid not in chunk_of:
            continue
        doc = _episode_record(sid, cols, scenario_tracks, steps_by.get(sid), segs,
                              labelled_tracks)
        chunks.setdefault(chunk_of[sid], []).append(doc)
    return chunks


def _number(value: Any, digits: int) -> float | None:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return round(v, digits) if np.isfinite(v) else None


def _text(value: Any) -> str:
    return "" if value is None or value is pd.NA or (isinstance(value, float)
                                                     and np.isnan(value)) else str(value)


def episode_index(episodes: pd.DataFrame, *, novel_labels: pd.DataFrame | None = None,
                  chunk_by: Iterable[str] = ("env", "seed"),
                  has_replay: Iterable[str] = (),
                  measures: Iterable[Mapping[str, Any]] | None = None,
                  scenes: Mapping[str, str] | None = None
                  ) -> tuple[pd.DataFrame, list[dict[str, Any]]]:
    """The list entries of the viewer, one per episode.

    Args:
        episodes: the episode table (:mod:`tap_bench.bench.episodes`).
        novel_labels: the run's ``novel_labels`` table: an episode is novel against a
            reference when its env, policy and label appear there.
        chunk_by: the columns whose values name an episode's chunk (every policy on one env
            and seed loads together).
        has_replay: scenario ids with trajectories (the others are listed without replay).
        measures: the measure entries shown (:meth:`~tap_bench.bench.measures.Measure.
            to_dict`; default: every registered one); each entry's ``measures`` holds their
            values by name.
        scenes: episode ``scenario_id`` -> the scenario id of the recorded (WOMD) scene it
            drove (a run's ``womd_scenario_id``); those episodes are named by it.

    Returns:
        the episode table with a ``chunk`` column, and the list entries; each entry's
        ``name`` is how the page names the episode (:func:`episode_name`).
    """
    eps = episodes.copy()
    keys = list(chunk_by)
    eps["chunk"] = [_chunk_name([str(v) for v in vals])
                    for vals in eps[keys].itertuples(index=False)]
    novel: dict[tuple[str, str, str], list[str]] = {}
    if novel_labels is not None and len(novel_labels):
        for r in novel_labels[["env", "policy", "label", "reference"]].itertuples(index=False):
            novel.setdefault((str(r.env), str(r.policy), str(r.label)), []).append(
                str(r.reference))
    replay = set(map(str, has_replay))
    shown = ([dict(m) for m in measures] if measures is not None else
        [m.to_dict() for m in MEASURES])
    entries = []
    for r in eps.to_dict("records"):
        sdl = _text(r.get("sdl"))
        entry = {
            "id": _text(r.get("scenario_id")) or f"{r['env']}/{r['policy']}/s{r['seed']}",
            "env": _text(r.get("env")), "policy": _text(r.get("policy")),
            "seed": int(r["seed"]), "chunk": r["chunk"],
            "name": episode_name(_text(r.get("env")), int(r["seed"]),
                                 (scenes or {}).get(_text(r.get("scenario_id")))),
            "ok": r.get("status", "ok") == "ok", "error": _text(r.get("error")),
            "replay": _text(r.get("scenario_id")) in replay,
            "crashed": bool(r.get("crashed")) if not pd.isna(r.get("crashed")) else False,
            "sdl": sdl, "lateral": _text(r.get("lateral")),
            "longitudinal": _text(r.get("longitudinal")),
            "interaction": _text(r.get("interaction")),
            "novel": sorted(set(novel.get((_text(r.get("env")), _text(r.get("policy")), sdl),
                                          []))),
            "measures": {m["name"]: _number(r.get(m["name"]), int(m.get("decimals", 2)) + 2)
                         for m in shown},
        }
        entries.append(entry)
    return eps, entries


def episode_name(env: str, seed: int, scene: str | None = None) -> str:
    """How the viewer names an episode (list, pane titles): a recorded scene's episode by
    its scenario id, ``"scenario <id>"`` (on real scenes episodes are paired by scenario
    id, SPEC section 8), a highway-env episode by ``"<env> · seed <N>"``."""
    return f"scenario {scene}" if scene else f"{env} · seed {seed}"


def _slug(text: str) -> str:
    return "".join(c if c.isascii() and (c.isalnum() or c in "-_.") else "_" for c in text)


_MAX_CHUNK_NAME = 100  # bytes of a chunk's file name, ".js" aside (file systems allow 255)
_RESERVED = {"index"}  # data/index.js is the viewer's own


def _chunk_name(values: list[str]) -> str:
    """The file name (without ``.js``) of the chunk of ``values``: their slugs joined by
    ``-``; a name that would be too long, reserved (``index``), start with a dot or stand
    for other text is cut and ends with 16 hex digits of the values' SHA-256, so distinct
    values never share or overwrite a file."""
    name = "-".join(_slug(v) for v in values)
    if (len(name) <= _MAX_CHUNK_NAME and name.lower() not in _RESERVED
            and not name.startswith(".") and name == "-".join(values)):
        return name
    digest = hashlib.sha256("\0".join(values).encode("utf-8", "surrogatepass")).hexdigest()
    return f"{name.lstrip('.')[:_MAX_CHUNK_NAME - 17]}-{digest[:16]}"
