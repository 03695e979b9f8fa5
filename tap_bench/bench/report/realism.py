"""The report's section on the realism of simulated traffic (SPEC section 9).

A run carries the results of ``tap-bench realism`` it was given (``tap-bench bench
--realism FILE.json ...``, :func:`realism_entries`) in ``summary.json`` under ``realism``;
:func:`realism_section` shows them: each traffic model's meta-metric with its interval over
scenes and its feature likelihoods, then the meta-metric by the logged agent's manoeuvre, so
the reactive traffic reads between its floor (constant velocity) and its ceiling (the log
scored against itself).
"""

from __future__ import annotations

import html
import json
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from tap_bench.bench.report.tables import html_table
from tap_bench.errors import ParameterError

__all__ = ["realism_entries", "realism_section"]

_KEPT = ("traffic", "policy", "rollouts", "scenes", "agents", "weights", "overall",
         "by_manoeuvre", "by_object_type", "interval", "definition")
_ORDER = {"constant-velocity": 0, "idm": 1, "log": 2}


def realism_entries(results: Sequence[str | os.PathLike | Mapping[str, Any]]
                    ) -> list[dict[str, Any]]:
    """The parts of ``tap-bench realism`` results a report shows, from their JSON files (or
    the results as dicts).

    Raises:
        ParameterError: a file that cannot be read as a realism result (naming the file,
            the field missing and the fix).
    """
    out = []
    for item in results:
        name = str(item) if not isinstance(item, Mapping) else "a realism result"
        if isinstance(item, Mapping):
            result = dict(item)
        else:
            try:
                result = json.loads(Path(item).read_text())
            except (OSError, ValueError) as err:
                raise ParameterError("--realism", name, "the JSON file `tap-bench realism "
                                     f"-o FILE` writes ({err})") from err
        missing = [k for k in ("traffic", "overall", "by_manoeuvre") if k not in result]
        if not isinstance(result, dict) or missing:
            raise ParameterError("--realism", name, "a result of `tap-bench realism -o FILE` "
                                 f"(fields {', '.join(missing)} missing): write it again")
        out.append({k: result.get(k) for k in _KEPT})
    return sorted(out, key=lambda r: (_ORDER.get(str(r["traffic"]), 1), str(r["traffic"])))


def _ci(block: Mapping[str, Any] | None) -> str:
    if (not block or not isinstance(block.get("value"), int | float)
            or not math.isfinite(block["value"])):
        return "–"
    lo, hi = block.get("low"), block.get("high")
    if isinstance(lo, int | float) and isinstance(hi, int | float) and math.isfinite(lo):
        return f"{block['value']:.3f} [{lo:.3f}, {hi:.3f}]"
    return f"{block['value']:.3f}"


def realism_section(entries: Sequence[Mapping[str, Any]]) -> list[str]:
    """HTML of the realism section: one table of the traffic models, one by manoeuvre."""
    if not entries:
        return []
    features = [f for f in (entries[0].get("weights") or {})]
    rows = []
    for r in entries:
        overall = r.get("overall") or {}
        row = {"traffic": str(r.get("traffic")), "ego": str(r.get("policy")),
               "rollouts K": r.get("rollouts"), "scenes": r.get("scenes"),
               "agents": r.get("agents"), "meta-metric [interval]":
               _ci(overall.get("meta_metric"))}
        for f in features:
            block = overall.get(f) or {}
            value = block.get("value")
            row[f.replace("_", " ")] = (f"{value:.3f}" if isinstance(value, int | float)
                and math.isfinite(value) else "–")
        rows.append(row)
    manoeuvres = sorted({m for r in entries for m in (r.get("by_manoeuvre") or {})})
    by = []
    for m in manoeuvres:
        row = {"manoeuvre": m}
        for r in entries:
            block = (r.get("by_manoeuvre") or {}).get(m) or {}
            row[str(r.get("traffic"))] = _ci(block.get("meta_metric"))
            row[f"agents ({r.get('traffic')})"] = block.get("agents", 0)
        by.append(row)
    interval = html.escape(str(entries[0].get("interval") or ""))
    return ["<h2>Realism of the simulated traffic</h2>",
            '<p class="note">How much the simulated agents drive like the people they replace '
            "on recorded scenes: WOSAC 2025's meta-metric (0-1, higher is more realistic; "
            "docs/realism.md), the traffic models side by side. Constant velocity is the "
            "floor, the log scored against itself the ceiling: a realistic model sits "
            f"between them. {interval}</p>",
            html_table(pd.DataFrame(rows), caption="Meta-metric and feature likelihoods per "
                       "traffic model", table_id="realism", text_columns=["traffic", "ego"]),
            html_table(pd.DataFrame(by), caption="Meta-metric by the logged agent's TAP "
                       "manoeuvre", table_id="realism-manoeuvre",
                       text_columns=["manoeuvre"])]
