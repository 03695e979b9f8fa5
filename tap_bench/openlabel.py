"""Labels as ASAM OpenLABEL 1.0.0 JSON, and back.

One OpenLABEL document per scenario, from a segment table (SPEC section 1, one row per run
of one label; with interactions, ``axis = "interaction"`` rows naming ``other_track_id``):

- ``metadata``: ``schema_version`` 1.0.0, ``annotator`` tap-bench, ``name`` the scenario id;
  ``tap_bench`` the level and the frame rate;
- ``ontologies["0"]``: the tap-bench SDL vocabulary (every label of the three axes);
- ``objects``: one per labelled track, uid its index in the scenario, ``name`` and ``type``
  (``object_type``, else ``vehicle``), ``object_data.text`` its ``track_id`` (and
  ``ego`` for the ego);
- ``actions``: one per run: ``type`` the label (``Left Merge``, ``Decelerate``,
  ``Cut-in``), ``name`` ``"<axis>: <label>"``, ``frame_intervals`` its steps (frame =
  round(10 t); ``frame_end`` inclusive), ``action_data``: text ``axis`` and ``level``, num
  ``t_start`` and ``t_end`` [s] (exact, ``t_end`` exclusive as in the segment table);
- ``relations``: the track ``isSubjectOfAction`` of each of its runs; on the interaction
  axis the other agent ``isObjectOfAction`` of the run (OpenLABEL's RDF predicates);
- ``frame_intervals``: the scenario's labelled frames.

:func:`read_openlabel` turns documents back into the segment table (the test checks the
round trip and validates every document against the OpenLABEL JSON schema).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tap_bench import sdl
from tap_bench.errors import FileFormatError, LabelTableError
from tap_bench.tableio import atomic_folder, atomic_path, check_folder_output, check_replace
from tap_bench.trajectories import HZ

__all__ = ["OPENLABEL_VERSION", "read_openlabel", "to_openlabel", "write_openlabel"]

OPENLABEL_VERSION = "1.0.0"
ONTOLOGY_URI = "https://github.com/tap-bench/tap-bench/docs/tap.md#sdl-vocabulary"
_SEGMENT_COLUMNS = ("scenario_id", "track_id", "axis", "label", "t_start", "t_end")


def _frame(t: float) -> int:
    return round(float(t) * HZ)


def to_openlabel(segments: pd.DataFrame, *, level: str | None = None,
                 source: str = "segment table") -> dict[str, dict[str, Any]]:
    """OpenLABEL documents of a segment table: scenario id -> document.

    Args:
        segments: a segment table (``tap(...).segments(level)``), optionally with
            ``other_track_id``, ``object_type``, ``is_ego``.
        level: the level to export when the table holds several (default: its only one).
        source: a name for the table in error messages.

    Raises:
        LabelTableError: missing columns, several levels and none chosen, or a negative time.
    """
    missing = [c for c in _SEGMENT_COLUMNS if c not in segments.columns]
    if missing:
        raise LabelTableError(f"{source}: not a segment table (missing "
                              f"{', '.join(missing)}); make one with 'tap-bench label "
                              "--segments FILE' (with --interactions for the interaction axis).")
    table = segments
    if "level" in table.columns:
        levels = [lv for lv in sdl.LEVELS if lv in set(table["level"].astype(str))]
        if level is None:
            if len(levels) != 1:
                raise LabelTableError(f"{source}: the table holds levels {', '.join(levels)}; "
                                      "choose one (--level).")
            level = levels[0]
        elif level not in levels:
            raise LabelTableError(f"{source}: no rows at level {level!r}; it holds "
                                  f"{', '.join(levels)}.")
        table = table[table["level"].astype(str) == level]
    if (table["t_start"].to_numpy(float) < 0).any():
        row = int(np.flatnonzero(table["t_start"].to_numpy(float) < 0)[0])
        raise LabelTableError(f"{source}: row {row} starts at t = "
                              f"{table['t_start'].iloc[row]} s; OpenLABEL frames count from 0: "
                              "shift the times to start at 0.")
    docs = {}
    for sid, scene in table.groupby("scenario_id", sort=True):
        docs[str(sid)] = _document(str(sid), scene.reset_index(drop=True), level)
    return docs


def _document(sid: str, scene: pd.DataFrame, level: str | None) -> dict[str, Any]:
    tracks = list(dict.fromkeys(scene["track_id"].astype(str)))
    others = ([] if "other_track_id" not in scene.columns else
        [str(o) for o in scene["other_track_id"].dropna().astype(str)])
    for other in others:  # an agent named by a relation is an object too
        if other not in tracks:
            tracks.append(other)
    uid = {track: str(k) for k, track in enumerate(tracks)}
    first = scene.drop_duplicates("track_id").set_index(scene.drop_duplicates("track_id")
                                                        ["track_id"].astype(str))
    objects = {}
    for track in tracks:
        kind = "vehicle"
        texts = [{"name": "track_id", "val": track}]
        if track in first.index:
            row = first.loc[track]
            if "object_type" in first.columns and pd.notna(row["object_type"]):
                kind = str(row["object_type"])
            if "is_ego" in first.columns and bool(row["is_ego"]) and pd.notna(row["is_ego"]):
                texts.append({"name": "role", "val": "ego"})
        mine = scene[scene["track_id"].astype(str) == track]
        obj: dict[str, Any] = {"name": track, "type": kind, "object_data": {"text": texts}}
        if len(mine):
            obj["frame_intervals"] = [{"frame_start": _frame(mine["t_start"].min()),
                                       "frame_end": _frame(mine["t_end"].max()) - 1}]
        objects[uid[track]] = obj
    actions, relations = {}, {}
    for k, run in enumerate(scene.itertuples(index=False)):
        interval = [{"frame_start": _frame(run.t_start), "frame_end": _frame(run.t_end) - 1}]
        actions[str(k)] = {
            "name": f"{run.axis}: {run.label}", "type": str(run.label), "ontology_uid": "0",
            "frame_intervals": interval,
            "action_data": {
                "text": [{"name": "axis", "val": str(run.axis)},
                         {"name": "level", "val": str(level or "")}],
                "num": [{"name": "t_start", "val": float(run.t_start)},
                        {"name": "t_end", "val": float(run.t_end)}]}}
        relations[str(len(relations))] = {
            "name": f"{run.track_id} {run.label}", "type": "isSubjectOfAction",
            "frame_intervals": interval,
            "rdf_subjects": [{"uid": uid[str(run.track_id)], "type": "object"}],
            "rdf_objects": [{"uid": str(k), "type": "action"}]}
        other = getattr(run, "other_track_id", None)
        if other is not None and pd.notna(other):
            relations[str(len(relations))] = {
                "name": f"{other} in {run.track_id}'s {run.label}", "type": "isObjectOfAction",
                "frame_intervals": interval,
                "rdf_subjects": [{"uid": uid[str(other)], "type": "object"}],
                "rdf_objects": [{"uid": str(k), "type": "action"}]}
    vocabulary = [t for axis in sdl.LABEL_AXES
                  for t in dict.fromkeys(x for lv in sdl.LEVELS for x in sdl.vocabulary(lv,
                                                                                      axis))]
    return {"openlabel": {
        "metadata": {"schema_version": OPENLABEL_VERSION, "annotator": "tap-bench (TAP)",
                     "name": sid, "comment": "TAP SDL labels: lateral, longitudinal and "
                     "interaction runs of each track",
                     "tap_bench": {"level": level, "frame_rate_hz": HZ}},
        "ontologies": {"0": {"uri": ONTOLOGY_URI, "boundary_list": vocabulary,
                             "boundary_mode": "include"}},
        "frame_intervals": [{"frame_start": _frame(scene["t_start"].min()),
                             "frame_end": _frame(scene["t_end"].max()) - 1}],
        "objects": objects, "actions": actions, "relations": relations}}


MAX_NAME_BYTES = 200
"""The longest file name made from a scenario id [B] (file systems allow 255): a longer id
is cut and ends with 16 hex digits of its SHA-256, so distinct ids stay distinct files."""


def _file_name(sid: str) -> str:
    """``<scenario_id>.json`` with unsafe characters as ``_``, within :data:`MAX_NAME_BYTES`."""
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", sid).lstrip(".") or "_"
    if len(name) > MAX_NAME_BYTES - 5:  # ASCII only by now: characters are bytes
        digest = hashlib.sha256(sid.encode("utf-8", "surrogatepass")).hexdigest()[:16]
        name = f"{name[:MAX_NAME_BYTES - 5 - 17]}-{digest}"
    return name + ".json"


def write_openlabel(segments: pd.DataFrame, output: str | os.PathLike, *,
                    level: str | None = None, source: str = "segment table",
                    overwrite: bool = False) -> list[Path]:
    """Write one OpenLABEL JSON per scenario: a ``.json`` file when the table holds one
    scenario, else a new folder of ``<scenario_id>.json`` (built whole beside it and renamed
    into place, with tap-bench's folder marker; a scenario id too long for a file name is
    cut and ends with a hash).

    Args:
        overwrite: replace an existing ``.json`` file, or a folder an earlier export wrote
            (never one tap-bench did not write, nor one holding files it did not write).

    Raises:
        RunExistsError: ``output`` exists and ``overwrite`` is False.
        OutputPathError: ``output`` exists and tap-bench did not write it.
    """
    docs = to_openlabel(segments, level=level, source=source)
    output = Path(output)
    if output.suffix == ".json":
        if len(docs) != 1:
            raise FileFormatError(f"{output}: the table holds {len(docs)} scenarios and "
                                  "OpenLABEL describes one each; give a directory instead.")
        check_replace([output], overwrite)
        (sid,) = docs
        with atomic_path(output) as tmp:
            tmp.write_text(json.dumps(docs[sid], indent=1) + "\n")
        return [output]
    check_folder_output(output, overwrite)
    names = {sid: _file_name(sid) for sid in docs}
    if len(set(names.values())) != len(names):
        raise FileFormatError(f"{output}: two scenario ids give one file name; rename "
                              "them apart.")
    with atomic_folder(output, overwrite, kind="openlabel") as tmp:
        for sid, name in names.items():
            (tmp / name).write_text(json.dumps(docs[sid], indent=1) + "\n")
    return [output / name for name in names.values()]


def read_openlabel(documents: str | os.PathLike | Mapping[str, Any]
                   | Iterable[str | os.PathLike | Mapping[str, Any]]) -> pd.DataFrame:
    """The segment table of OpenLABEL documents written by :func:`write_openlabel`.

    Args:
        documents: a JSON file, a directory of them, a parsed document, or several.

    Returns:
        scenario_id, track_id, level, axis, label, t_start, t_end, other_track_id.

    Raises:
        FileFormatError: not OpenLABEL, or an action without its axis or times.
    """
    if isinstance(documents, Mapping):
        items: list[Any] = [documents]
    elif isinstance(documents, str | os.PathLike):
        path = Path(documents)
        items = sorted(path.glob("*.json")) if path.is_dir() else [path]
    else:
        items = list(documents)
    rows = []
    for item in items:
        where = str(item) if not isinstance(item, Mapping) else "document"
        doc = item if isinstance(item, Mapping) else _load(Path(item))
        ol = doc.get("openlabel") if isinstance(doc, Mapping) else None
        if not isinstance(ol, Mapping) or "metadata" not in ol:
            raise FileFormatError(f"{where}: not an OpenLABEL document (no 'openlabel' root "
                                  "with 'metadata').")
        sid = str(ol["metadata"].get("name", Path(where).stem))
        objects = ol.get("objects", {})
        subject, other = {}, {}
        for rel in ol.get("relations", {}).values():
            target = {o["uid"] for o in rel.get("rdf_objects", []) if o.get("type") == "action"}
            agent = [s["uid"] for s in rel.get("rdf_subjects", []) if s.get("type") == "object"]
            for action in target:
                if rel["type"] == "isSubjectOfAction" and agent:
                    subject[action] = agent[0]
                elif rel["type"] == "isObjectOfAction" and agent:
                    other[action] = agent[0]
        for key, action in ol.get("actions", {}).items():
            data = action.get("action_data", {})
            text = {t.get("name"): t.get("val") for t in data.get("text", [])}
            num = {t.get("name"): t.get("val") for t in data.get("num", [])}
            if "axis" not in text or "t_start" not in num or key not in subject:
                raise FileFormatError(f"{where}: action {key} lacks its axis, times or "
                                      "subject; it was not written by tap-bench.")
            rows.append({"scenario_id": sid, "track_id": _track(objects, subject[key]),
                         "level": text.get("level") or None, "axis": text["axis"],
                         "label": action["type"], "t_start": float(num["t_start"]),
                         "t_end": float(num["t_end"]),
                         "other_track_id": _track(objects, other[key]) if key in other
                         else None})
    out = pd.DataFrame(rows, columns=["scenario_id", "track_id", "level", "axis", "label",
                                      "t_start", "t_end", "other_track_id"])
    for col in ("scenario_id", "track_id", "level", "axis", "label", "other_track_id"):
        out[col] = out[col].astype("string")
    return out


def _track(objects: Mapping[str, Any], uid: str) -> str:
    """The track id of an OpenLABEL object (its ``track_id`` text, else its name)."""
    obj = objects.get(uid, {})
    texts = {t.get("name"): t.get("val") for t in obj.get("object_data", {}).get("text", [])}
    return str(texts.get("track_id", obj.get("name", uid)))


def _load(path: Path) -> Any:
    if not path.is_file():
        raise FileFormatError(f"{path}: no such OpenLABEL file.")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise FileFormatError(f"{path}: not valid JSON: {err}") from err
