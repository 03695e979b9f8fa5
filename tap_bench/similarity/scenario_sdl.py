"""Scenario-level SDL and the Scenario2Vector weighted set distance (SPEC section 5).

A scenario S is described as SDL(S) = <{actors, actions}, elements> (Scenario2Vector,
eq. 1). tap-bench reads the three parts from the tables it already has:

- **actors**: the object types (``vehicle``, ``pedestrian``, ``cyclist``, ``other``) of the
  tracks around the ego: every other track, or, with ``radius`` and the trajectory table,
  those that come within ``radius`` metres of the ego at a common time step;
- **actions**: every SDL token (lateral and longitudinal) at the chosen level, tagged with
  the role of the track that performs it: ``ego: Left Merge``, ``vehicle: Stopped`` (the paper
  ties each action to its actor); without an ``is_ego`` column every track is tagged by its
  object type;
- **elements**: scene elements where the data has them: ``env=...`` (the highway-env
  scenario) and ``road_type=...`` columns, or any column named in ``element_columns``.

The distance from a query Si to a candidate Sj counts what is missing from Sj and what is
extra in Sj, per part: D = <|AC_ij|, |AC_ji|, |AT_ij|, |AT_ji|, |E_ij|, |E_ji|>, weighted
<6, 3, 18, 9, 2, 1>; d = ||w * D|| (Euclidean). It is not symmetric: a missing action costs
twice an extra one. Ties: a candidate with the same action set as the query ranks first,
then the order of the candidates.

Parts are sets, as in the paper. ``multiset=True`` counts instead (three vehicles against
one is two missing vehicles), which separates busy scenes from quiet ones.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from tap_bench.errors import LabelTableError, ParameterError, did_you_mean
from tap_bench.sdl import parse_sdl
from tap_bench.similarity.sdl_distance import label_set
from tap_bench.trajectories import DT, validate_and_index

__all__ = [
    "DISTANCE_PARTS",
    "WEIGHTS",
    "ScenarioDescription",
    "ScenarioSet",
    "distance_vector",
    "rank_scenarios",
    "scenario_distance",
    "scenario_set",
]

PARTS = ("actors", "actions", "elements")
DISTANCE_PARTS = ("missing_actors", "extra_actors", "missing_actions", "extra_actions",
                  "missing_elements", "extra_elements")
"""The six counts of the distance vector D, in the order of :data:`WEIGHTS`."""
WEIGHTS = (6.0, 3.0, 18.0, 9.0, 2.0, 1.0)
"""Scenario2Vector's weights: actions 9x actors 3x elements, a missing item 2x an extra one."""
DEFAULT_ELEMENT_COLUMNS = ("env", "road_type")
EGO_ROLE = "ego"


def _counter(items: Iterable[str] | Mapping[str, int] | None) -> Counter:
    if items is None:
        return Counter()
    if isinstance(items, Mapping):
        return Counter({str(k): int(v) for k, v in items.items() if int(v) > 0})
    if isinstance(items, str):
        raise TypeError(f"expected a collection of names, got the string {items!r}; wrap it in "
                        "a list")
    return Counter(str(i) for i in items)


@dataclass(frozen=True)
class ScenarioDescription:
    """SDL(S) = <{actors, actions}, elements> of one scenario.

    Each part maps a name to how often it occurs (1 for every name in set semantics).
    Build one from plain collections: ``ScenarioDescription.of(actions=["Forward", "Turn"])``.
    """

    actors: Counter
    actions: Counter
    elements: Counter

    @classmethod
    def of(cls, actors: Iterable[str] | Mapping[str, int] | None = None,
           actions: Iterable[str] | Mapping[str, int] | None = None,
           elements: Iterable[str] | Mapping[str, int] | None = None, *,
           multiset: bool = False) -> ScenarioDescription:
        """A description from collections of names (duplicates count only with multiset)."""
        parts = [_counter(p) for p in (actors, actions, elements)]
        if not multiset:
            parts = [Counter(dict.fromkeys(p, 1)) for p in parts]
        return cls(*parts)

    def part(self, name: str) -> Counter:
        return getattr(self, name)


def distance_vector(query: ScenarioDescription, other: ScenarioDescription) -> np.ndarray:
    """(6,) int64: missing and extra actors, actions and elements of ``other`` w.r.t. ``query``.

    Missing items are in the query but not in ``other``; extra items the reverse.
    """
    out = []
    for part in PARTS:
        q, o = query.part(part), other.part(part)
        out += [sum((q - o).values()), sum((o - q).values())]
    return np.asarray(out, dtype=np.int64)


def scenario_distance(query: ScenarioDescription, other: ScenarioDescription,
                      weights: Sequence[float] = WEIGHTS) -> float:
    """d(Si, Sj) = || w * D_ij ||, Scenario2Vector's weighted set distance (not symmetric).

    >>> a = ScenarioDescription.of(actions=["Forward", "Turn"])
    >>> b = ScenarioDescription.of(actions=["Turn", "Stop"])
    >>> round(scenario_distance(a, b), 4)   # sqrt(18**2 + 9**2)
    20.1246
    """
    w = _weights(weights)
    return float(np.linalg.norm(w * distance_vector(query, other)))


def _weights(weights: Sequence[float]) -> np.ndarray:
    w = np.asarray(weights, dtype=np.float64)
    if w.shape != (6,) or not np.all(np.isfinite(w)) or (w < 0).any():
        raise ParameterError("weights", weights, "",
            message=f"weights must be six finite numbers >= 0 ({', '.join(DISTANCE_PARTS)}),"
                    f" got {weights!r}")
    return w


@dataclass(frozen=True)
class ScenarioSet:
    """The scenario-level SDL of many scenarios, as count matrices over a vocabulary.

    Attributes:
        scenario_ids: (s,) object array of scenario ids, in first-appearance order.
        vocabulary: part name -> names indexing the columns of that part's matrix.
        counts: part name -> (s, V) int32 occurrence counts (0/1 in set semantics).
        multiset: whether parts count occurrences.
    """

    scenario_ids: np.ndarray
    vocabulary: dict[str, tuple[str, ...]]
    counts: dict[str, np.ndarray]
    multiset: bool = False

    def __len__(self) -> int:
        return len(self.scenario_ids)

    @classmethod
    def from_descriptions(cls, descriptions: Mapping[str, ScenarioDescription], *,
                          multiset: bool = False) -> ScenarioSet:
        """A set from scenario id -> description (hand-written SDLs, other data sets)."""
        ids = np.asarray([str(k) for k in descriptions], dtype=object)
        vocabulary, counts = {}, {}
        for part in PARTS:
            names = tuple(sorted({n for d in descriptions.values() for n in d.part(part)}))
            col = {n: k for k, n in enumerate(names)}
            mat = np.zeros((len(ids), len(names)), dtype=np.int32)
            for i, d in enumerate(descriptions.values()):
                for name, c in d.part(part).items():
                    mat[i, col[name]] = c if multiset else min(c, 1)
            vocabulary[part], counts[part] = names, mat
        return cls(scenario_ids=ids, vocabulary=vocabulary, counts=counts, multiset=multiset)

    def index(self, scenario_id: str) -> int:
        hit = np.flatnonzero(self.scenario_ids == str(scenario_id))
        if len(hit) == 0:
            raise did_you_mean("scenario_id", str(scenario_id), self.scenario_ids.tolist())
        return int(hit[0])

    def description(self, scenario: int | str) -> ScenarioDescription:
        """The :class:`ScenarioDescription` of one scenario (by position or id)."""
        i = self.index(scenario) if isinstance(scenario, str) else int(scenario)
        parts = []
        for part in PARTS:
            row = self.counts[part][i]
            names = self.vocabulary[part]
            parts.append(Counter({names[k]: int(row[k]) for k in np.flatnonzero(row)}))
        return ScenarioDescription(*parts)


def _ego_mask(table: pd.DataFrame) -> np.ndarray:
    if "is_ego" not in table.columns:
        return np.zeros(len(table), dtype=bool)
    return table["is_ego"].fillna(False).astype(bool).to_numpy()


def _near_ego(trajectories: pd.DataFrame, radius: float, source: str) -> pd.DataFrame:
    """(scenario_id, track_id) of the tracks within ``radius`` m of their scenario's ego."""
    checked = validate_and_index(trajectories, source=source)
    frame = pd.DataFrame({
        "scenario_id": np.asarray(checked["scenario_id"], dtype=object),
        "track_id": np.asarray(checked["track_id"], dtype=object),
        "step": np.round(np.asarray(checked["t"]) / DT).astype(np.int64),
        "x": checked["x"], "y": checked["y"],
    })
    frame = frame[np.asarray(checked["valid"], dtype=bool)]
    if "is_ego" not in checked:
        raise LabelTableError(f"{source}: radius needs an ego: the trajectory table has no "
                              "'is_ego' column. Drop the radius, or mark the ego track.")
    ego = frame[np.asarray(checked["is_ego"], dtype=bool)[np.asarray(checked["valid"],
                                                                      dtype=bool)]]
    pairs = frame.merge(ego[["scenario_id", "step", "x", "y"]], on=["scenario_id", "step"],
                        suffixes=("", "_ego"))
    dist = np.hypot(pairs["x"] - pairs["x_ego"], pairs["y"] - pairs["y_ego"])
    near = pairs.loc[dist.to_numpy() <= radius, ["scenario_id", "track_id"]]
    return near.drop_duplicates()


def scenario_set(labels: pd.DataFrame, trajectories: pd.DataFrame | None = None, *,
                 level: str | None = "action", radius: float | None = None,
                 element_columns: Sequence[str] = DEFAULT_ELEMENT_COLUMNS,
                 multiset: bool = False, source: str = "label table") -> ScenarioSet:
    """Build the scenario-level SDL of every scenario of a label table.

    Args:
        labels: a label table (SPEC section 1); ``object_type`` and ``is_ego`` give roles.
        trajectories: the trajectory table, needed for ``radius`` and read for element
            columns the label table lacks (``road_type`` ...).
        level: the SDL level of the actions.
        radius: keep as actors only tracks within this distance of the ego [m].
        element_columns: per-track columns whose values are scene elements.
        multiset: count actors and actions instead of collecting sets.
        source: a name for the label table in error messages.

    Returns:
        A :class:`ScenarioSet` with one row per scenario of ``labels``.
    """
    ls = label_set(labels, level, source=source)
    table = ls.table
    role = (table["object_type"].astype(str).to_numpy(dtype=object)
            if "object_type" in table.columns else np.full(len(table), "vehicle", dtype=object))
    ego = _ego_mask(table)
    role = np.where(ego, EGO_ROLE, role)
    keep = np.ones(len(table), dtype=bool)
    if radius is not None:
        if trajectories is None:
            raise LabelTableError("radius needs the trajectory table (positions of the ego and "
                                  "the other tracks); pass trajectories=... (--trajectories).")
        if not radius > 0:
            raise ParameterError("radius", radius, "",
                message=f"radius must be > 0 m, got {radius!r}")
        near = _near_ego(trajectories, radius, "trajectory table")
        key = pd.MultiIndex.from_frame(table[["scenario_id", "track_id"]].astype(str))
        near_key = pd.MultiIndex.from_frame(near.astype(str))
        has_ego = pd.Series(ego).groupby(table["scenario_id"].astype(str).to_numpy()).transform(
            "any").to_numpy()
        keep = ego | ~has_ego | key.isin(near_key)

    elements = _elements(table, trajectories, element_columns)
    scen = table["scenario_id"].astype(str).to_numpy(dtype=object)
    scenario_ids = np.asarray(pd.unique(scen), dtype=object)
    s_index = {s: i for i, s in enumerate(scenario_ids)}

    rows: dict[str, list[tuple[int, str]]] = {p: [] for p in PARTS}
    tokens_of = {u: parse_sdl(str(text), level=ls.level) for u, text in enumerate(ls.labels)}
    track = table["track_id"].astype(str).to_numpy(dtype=object)
    seen_actor: set[tuple[str, str]] = set()
    seen_action: set[tuple[str, str, str]] = set()
    for i in np.flatnonzero(keep):
        s = s_index[scen[i]]
        if role[i] != EGO_ROLE and (scen[i], track[i]) not in seen_actor:
            seen_actor.add((scen[i], track[i]))
            rows["actors"].append((s, str(role[i])))
        lat, lon = tokens_of[int(ls.code[i])]
        for tok in (*lat, *lon):
            # A track doing an action in two segments, or twice, performs it once.
            if (scen[i], track[i], tok) not in seen_action:
                seen_action.add((scen[i], track[i], tok))
                rows["actions"].append((s, f"{role[i]}: {tok}"))
    for s_id, names in elements.items():
        if s_id in s_index:
            rows["elements"] += [(s_index[s_id], name) for name in names]

    vocabulary, counts = {}, {}
    for part in PARTS:
        names = tuple(sorted({name for _, name in rows[part]}))
        col = {n: k for k, n in enumerate(names)}
        mat = np.zeros((len(scenario_ids), len(names)), dtype=np.int32)
        for s, name in rows[part]:
            mat[s, col[name]] += 1
        if not multiset:
            mat = np.minimum(mat, 1)
        vocabulary[part], counts[part] = names, mat
    return ScenarioSet(scenario_ids=scenario_ids, vocabulary=vocabulary, counts=counts,
                       multiset=multiset)


def _elements(labels: pd.DataFrame, trajectories: pd.DataFrame | None,
              columns: Sequence[str]) -> dict[str, set[str]]:
    """scenario_id -> {'column=value'} over the element columns either table has."""
    out: dict[str, set[str]] = {}
    for frame in (labels, trajectories):
        if frame is None:
            continue
        for col in columns:
            if col not in frame.columns or col in ("scenario_id", "track_id"):
                continue
            pairs = frame[["scenario_id", col]].dropna().drop_duplicates()
            for s, v in zip(pairs["scenario_id"].astype(str), pairs[col].astype(str),
                            strict=True):
                if v:
                    out.setdefault(s, set()).add(f"{col}={v}")
    return out


def rank_scenarios(query: ScenarioDescription | str, candidates: ScenarioSet, *,
                   weights: Sequence[float] = WEIGHTS, top: int | None = None,
                   include_query: bool = False) -> pd.DataFrame:
    """Rank scenarios by their weighted set distance from a query, nearest first.

    Args:
        query: a :class:`ScenarioDescription` (from any data set: a highway-env scenario
            against WOMD scenarios works) or the id of a scenario in ``candidates``.
        candidates: the scenarios to rank.
        weights: the six weights of :data:`DISTANCE_PARTS`.
        top: keep only the first ``top`` rows.
        include_query: keep the query scenario itself when it is given by id.

    Returns:
        rank (1-based), scenario_id, distance, same_actions, and the six counts; sorted by
        distance, then same action set first, then candidate order.
    """
    w = _weights(weights)
    self_row = None
    if isinstance(query, str):
        self_row = candidates.index(query)
        query = candidates.description(self_row)
    n = len(candidates)
    d = np.zeros((n, 6), dtype=np.int64)
    same_actions = np.ones(n, dtype=bool)
    for k, part in enumerate(PARTS):
        names = candidates.vocabulary[part]
        col = {name: j for j, name in enumerate(names)}
        qv = np.zeros(len(names), dtype=np.int64)
        outside = 0
        for name, c in query.part(part).items():
            if name in col:
                qv[col[name]] = c
            else:
                outside += c  # in the query, in no candidate: missing from all
        mat = candidates.counts[part].astype(np.int64)
        d[:, 2 * k] = np.maximum(qv[None, :] - mat, 0).sum(axis=1) + outside
        d[:, 2 * k + 1] = np.maximum(mat - qv[None, :], 0).sum(axis=1)
        if part == "actions":
            same_actions = (outside == 0) & ((mat > 0) == (qv > 0)[None, :]).all(axis=1)
    dist = np.sqrt(((w[None, :] * d) ** 2).sum(axis=1))
    order = np.lexsort((np.arange(n), ~same_actions, dist))
    if self_row is not None and not include_query:
        order = order[order != self_row]
    if top is not None:
        order = order[:top]
    out = pd.DataFrame({"rank": np.arange(1, len(order) + 1),
                        "scenario_id": candidates.scenario_ids[order],
                        "distance": dist[order], "same_actions": same_actions[order]})
    for k, name in enumerate(DISTANCE_PARTS):
        out[name] = d[order, k]
    return out
