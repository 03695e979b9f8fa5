"""TAP labels of WOMD tracks validated against Waymo's own trajectory-type classifier.

:func:`validate_womd` labels a trajectory table with TAP, classifies its tracks as WOMD's
motion metrics do (:mod:`tap_bench.womd.trajectory_types`) and compares them on the
classifier's window: the strict one-category agreement, the direction alone, the
longitudinal side beside it, the full confusion table, and the glitch check of SPEC
section 2 (no track that travels less than 1 m carries a turn or a merge).
:func:`write_validation` writes the tables; ``tap-bench validate`` runs both on WOMD files.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from tap_bench.errors import ShortSegmentWarning
from tap_bench.labelling import tap
from tap_bench.tableio import atomic_path, write_table
from tap_bench.womd.trajectory_types import (
    START_INDEX,
    agreement_table,
    classify_trajectories,
    confusion_table,
    label_agreement,
)

__all__ = ["WaymoValidation", "compare_with_waymo", "validate_womd", "write_validation"]


@dataclass(frozen=True)
class WaymoValidation:
    """What :func:`validate_womd` found.

    Attributes:
        per_track: one row per classified track (:func:`label_agreement`'s columns, plus
            the track's glitch counts and ``still`` when TAP was run here).
        agreement: per trajectory type: strict, direction and longitudinal agreement.
        confusion: tracks per trajectory type and TAP category.
        summary: JSON-ready figures: tracks, shares, the still tracks with a turn or merge.
    """

    per_track: pd.DataFrame
    agreement: pd.DataFrame
    confusion: pd.DataFrame
    summary: dict


def compare_with_waymo(table: pd.DataFrame, steps: pd.DataFrame, *, level: str = "maneuver",
                       glitches: pd.DataFrame | None = None,
                       start_index: int = START_INDEX) -> WaymoValidation:
    """Compare per-step TAP labels with Waymo's classifier.

    Args:
        table: the trajectory table (with ``valid``, ``vx``, ``vy``).
        steps: its per-step TAP labels (:meth:`tap_bench.TapResult.steps`).
        level: the TAP level compared.
        glitches: :meth:`tap_bench.TapResult.glitches`, to check that no still track
            carries a turn or merge (skipped when None).
        start_index: the classifier's first step (WOMD: 10).
    """
    keys = ["scenario_id", "track_id"]
    types = classify_trajectories(table, start_index=start_index)
    per_track = label_agreement(types, steps, level=level)
    agreement = agreement_table(per_track)
    confusion = confusion_table(per_track)
    total = agreement.set_index("trajectory_type").loc["all"] if len(agreement) else None
    summary: dict = {
        "level": level, "start_index": start_index, "tracks": len(per_track),
        "labelled": int(per_track["labelled"].sum()),
    }
    summary["scenes"] = int(total["scenes"]) if total is not None else 0
    for name in ("strict", "direction", "longitudinal"):
        summary[name] = int(total[name]) if total is not None else 0
        for what in ("share", "low", "high"):
            summary[f"{name}_{what}"] = (float(total[f"{name}_{what}"])
                                         if total is not None else float("nan"))
    turns = per_track["trajectory_type"].str.contains("TURN")
    summary["turns"] = int(turns.sum())
    summary["turns_labelled_as_that_turn"] = int((turns & per_track["strict"]).sum())
    if glitches is not None:
        per_track = per_track.merge(glitches, on=keys, how="left")
        lateral = steps[f"{level}_lateral"].astype(str)
        moved = steps.assign(_turn=lateral.str.contains("Turn|Merge").to_numpy())
        turning = moved.groupby(keys, sort=False)["_turn"].any().rename("has_turn_or_merge")
        still = glitches.merge(turning.reset_index(), on=keys, how="left")
        still["has_turn_or_merge"] = still["has_turn_or_merge"].fillna(False).astype(bool)
        summary["tap_tracks"] = len(glitches)
        summary["still_tracks"] = int(still["still"].sum())
        summary["still_tracks_with_turn_or_merge"] = int(
            (still["still"] & still["has_turn_or_merge"]).sum())
        for col in ("heading_glitches", "speed_glitches", "reversing_steps"):
            summary[col] = int(glitches[col].sum())
            summary[f"tracks_with_{col}"] = int((glitches[col] > 0).sum())
    return WaymoValidation(per_track=per_track, agreement=agreement, confusion=confusion,
                           summary=summary)


def validate_womd(table: pd.DataFrame, thresholds="paper", config=None, plausibility=None, *,
                  object_types: tuple[str, ...] | None = ("vehicle",),
                  level: str = "maneuver", source: str = "trajectory table"
                  ) -> WaymoValidation:
    """Label ``table`` with TAP and compare it with Waymo's trajectory-type classifier.

    Args:
        table: a WOMD trajectory table (:func:`tap_bench.read_womd`).
        thresholds: a preset, thresholds JSON or :class:`~tap_bench.Thresholds`.
        config: :class:`~tap_bench.StageConfig` (defaults).
        plausibility: :class:`~tap_bench.kinematics.Plausibility` (defaults).
        object_types: the object types compared (default vehicles; None: all).
        level: the TAP level compared (maneuver).
        source: a name for the table in messages.
    """
    if object_types is not None and "object_type" in table.columns:
        table = table[table["object_type"].astype(str).str.lower().isin(object_types)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ShortSegmentWarning)
        result = tap(table, thresholds, config, plausibility=plausibility, source=source)
    out = compare_with_waymo(table, result.steps(), level=level, glitches=result.glitches())
    out.summary.update(source=source, object_types=list(object_types) if object_types
                       else "all", thresholds=str(thresholds) if isinstance(thresholds, str)
                       else "custom")
    return out


def _over_scenes(s: dict, name: str) -> str:
    """``, 95 % interval 61.2-70.4 % over 16 scenes`` (empty without the interval)."""
    low, high = s.get(f"{name}_low", float("nan")), s.get(f"{name}_high", float("nan"))
    if not (low == low and high == high):
        return ""
    return (f", 95 % interval {100 * low:.1f}-{100 * high:.1f} % over {s.get('scenes', 0)} "
            "scenes")


def markdown(v: WaymoValidation) -> str:
    """The agreement and confusion tables as Markdown, with the summary figures."""
    s = v.summary

    def table(frame: pd.DataFrame, index: bool) -> list[str]:
        frame = frame.reset_index() if index else frame
        text = frame.astype(str)
        return ["| " + " | ".join(map(str, text.columns)) + " |",
                "|" + "---|" * len(text.columns),
                *("| " + " | ".join(row) + " |" for row in text.itertuples(index=False))]

    lines = [
        "# TAP labels against Waymo's trajectory-type classifier",
        "",
        f"Data: `{s.get('source', '')}`, {s['tracks']} tracks classified "
        f"({s.get('object_types', '')}), {s['labelled']} with TAP labels in the window "
        f"(step {s['start_index']} to the last valid step); level {s['level']}.",
        "",
        f"- strict lateral agreement: {s['strict']} of {s['labelled']} "
        f"({100 * s['strict_share']:.1f} %{_over_scenes(s, 'strict')})",
        f"- direction only: {s['direction']} of {s['labelled']} "
        f"({100 * s['direction_share']:.1f} %{_over_scenes(s, 'direction')})",
        f"- longitudinal (STATIONARY all Stopped, others not): {s['longitudinal']} of "
        f"{s['labelled']} ({100 * s['longitudinal_share']:.1f} %"
        f"{_over_scenes(s, 'longitudinal')})",
        f"- turns and U-turns labelled as a turn that way: {s['turns_labelled_as_that_turn']}"
        f" of {s['turns']}",
    ]
    if "still_tracks" in s:
        lines += [
            f"- tracks that travel less than 1 m: {s['still_tracks']} of {s['tap_tracks']} "
            f"labelled, of them with a turn or merge: {s['still_tracks_with_turn_or_merge']}",
            f"- glitches repaired: {s['heading_glitches']} heading flips or jumps in "
            f"{s['tracks_with_heading_glitches']} tracks, {s['speed_glitches']} speed spikes "
            f"in {s['tracks_with_speed_glitches']} tracks, {s['reversing_steps']} reversing "
            f"steps in {s['tracks_with_reversing_steps']} tracks",
        ]
    lines += ["", "## Agreement per trajectory type", "", *table(v.agreement, False), "",
              "## Confusion table (tracks; rows: Waymo, columns: TAP in the window)", "",
              *table(v.confusion, True), ""]
    return "\n".join(lines)


def write_validation(v: WaymoValidation, out_dir: str | Path) -> list[Path]:
    """Write validation.json, validation.md, agreement.csv, confusion.csv and
    per_track.parquet into ``out_dir`` (each atomically); returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in (("validation.json", json.dumps(v.summary, indent=2, default=_plain)),
                       ("validation.md", markdown(v))):
        path = out / name
        with atomic_path(path) as tmp:
            tmp.write_text(text)
        written.append(path)
    written.append(write_table(v.agreement, out / "agreement.csv"))
    written.append(write_table(v.confusion.reset_index(), out / "confusion.csv"))
    written.append(write_table(v.per_track, out / "per_track.parquet"))
    return written


def _plain(value):
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot write {type(value).__name__} as JSON")
