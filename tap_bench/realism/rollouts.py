"""K rollouts of recorded scenes, their features, and the realism score per scene (SPEC 9).

:func:`scene_rollouts` drives ``tap_bench/womd-v0`` K times through one scene (rollout k is
the env's reset option ``rollout=k``: the same scene and k give the same episode) and keeps
every agent's states as arrays; :func:`scene_features` turns one set of states into the
features of :mod:`tap_bench.realism.features`; :func:`score_scene` scores the traffic (every
agent valid at the current time but the ego) against the log, one row per agent and feature
(:func:`tap_bench.realism.score.agent_log_likelihoods`) with the agent's object type and
manoeuvre (:func:`agent_manoeuvres`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from tap_bench.realism.features import (
    kinematic_features,
    nearest_object_distance,
    red_light_violations,
    road_edge_distance,
    time_to_collision,
)
from tap_bench.realism.score import WOSAC_2025, agent_log_likelihoods
from tap_bench.sim.road_edges import RoadEdges
from tap_bench.sim.womd_scene import CURRENT_STEP, Scene

__all__ = ["MANOEUVRE_MIN", "SceneStates", "agent_manoeuvres", "log_states", "scene_features",
           "scene_rollouts", "score_scene"]

MANOEUVRE_MIN = 1.0  # [s] a turn or merge this long makes the agent's manoeuvre


@dataclass(frozen=True)
class SceneStates:
    """States of a scene's agents over K rollouts (or the log, K = 1).

    Attributes:
        x, y, heading: (K, n, T) [m, rad], WOMD axes; NaN where invalid.
        valid: (K, n, T) bool.
    """

    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    valid: np.ndarray

    @property
    def rollouts(self) -> int:
        """K."""
        return self.x.shape[0]


def log_states(scene: Scene) -> SceneStates:
    """The log as one rollout."""
    return SceneStates(scene.x[None].astype(float), scene.y[None].astype(float),
                       scene.heading[None].astype(float), scene.valid[None].astype(bool))


def scene_rollouts(env: Any, index: int, policy: Any, rollouts: int) -> SceneStates:
    """Drive scene ``index`` of a ``tap_bench/womd-v0`` env ``rollouts`` times.

    Args:
        env: a :class:`~tap_bench.sim.womd_env.WomdEnv`.
        index: the scene's seed (index in the env's catalog).
        policy: a :class:`~tap_bench.sim.policies.Policy` driving the ego.
        rollouts: K.

    Steps after an episode ended early (the ego crashed or left the road) are invalid.
    """
    xs, ys, hs, vs = [], [], [], []
    for k in range(rollouts):
        obs, _ = env.reset(seed=index, options={"rollout": k})
        policy.reset(env, seed=index)
        done = False
        while not done:
            obs, _, terminated, truncated, _ = env.step(policy.act(obs))
            done = terminated or truncated
        rec = env.recorded_states()
        xs.append(rec["x"])
        ys.append(rec["y"])
        hs.append(rec["heading"])
        vs.append(rec["valid"])
    return SceneStates(np.stack(xs), np.stack(ys), np.stack(hs), np.stack(vs))


def scene_features(scene: Scene, x: np.ndarray, y: np.ndarray, heading: np.ndarray,
                   valid: np.ndarray, *, edges: RoadEdges | None = None,
                   first: int = 0, selves: np.ndarray | None = None
                   ) -> dict[str, np.ndarray]:
    """Every feature of one rollout (or the log) of a scene, (n, T) each (Bernoulli
    features per step, bool).

    Args:
        scene: the scene (sizes, map, signals, time step).
        x, y, heading, valid: (n, T) states, WOMD axes.
        edges: the scene's road edges indexed (built here when None).
        first: the interaction and map features are computed from this step on (NaN or
            False before it); the kinematic ones everywhere.
        selves: the rows whose interaction and map features are computed (default all).
    """
    dt = float(np.median(np.diff(scene.times))) if scene.n_steps > 1 else 0.1
    length = np.asarray(scene.length, float)
    width = np.asarray(scene.width, float)
    x = np.where(valid, x, np.nan)
    y = np.where(valid, y, np.nan)
    heading = np.where(valid, heading, np.nan)
    out = kinematic_features(x, y, heading, valid, dt)
    n, t = x.shape
    w = slice(first, t)
    xs, ys, hs, vs = x[:, w], y[:, w], heading[:, w], valid[:, w]

    def full(part: np.ndarray, fill: Any) -> np.ndarray:
        whole = np.full((n, t), fill, dtype=part.dtype)
        whole[:, w] = part
        return whole

    nearest = nearest_object_distance(xs, ys, hs, vs, length, width, selves=selves)
    out["distance_to_nearest_object"] = full(nearest, np.nan)
    with np.errstate(invalid="ignore"):
        out["collision_indication"] = full(nearest < 0.0, False)
    out["time_to_collision"] = full(time_to_collision(
        xs, ys, hs, vs, length, width, out["linear_speed"][:, w], selves=selves), np.nan)
    road = scene.road
    edges = edges if edges is not None else RoadEdges.from_polylines(road.road_edges)
    vehicles = np.asarray(scene.object_types) == "vehicle"
    measured = vehicles.copy()  # walkers and cyclists are off the road by right
    if selves is not None:
        measured &= np.isin(np.arange(n), selves)
    edge = road_edge_distance(xs, ys, hs, vs & measured[:, None], length, width, edges)
    out["distance_to_road_edge"] = full(edge, np.nan)
    out["offroad_indication"] = full(np.nan_to_num(edge, nan=-1.0) > 0.0, False)
    signals = road.signals
    lanes, widths, keep = [], [], []
    for j, lane_id in enumerate(signals.lane):
        lane = road.lanes.get(int(lane_id))
        if lane is not None and len(lane.centre) >= 2:
            lanes.append(lane.centre)
            widths.append(lane.width)
            keep.append(j)
    red = signals.red[:, keep] if keep else np.zeros((scene.n_steps, 0), bool)
    if red.shape[0] < t:  # signal states shorter than the record: none after
        red = np.vstack([red, np.zeros((t - red.shape[0], red.shape[1]), bool)])
    start = max(first - 1, 0)  # a crossing at `first` moves from the step before it
    violations = red_light_violations(
        x[:, start:], y[:, start:], heading[:, start:], valid[:, start:], lanes, widths,
        signals.stop_point[keep] if keep else np.zeros((0, 2)), red[start:t])
    out["traffic_light_violation"] = full(violations[:, first - start:] & vehicles[:, None],
                                          False)
    return out


def score_scene(scene: Scene, simulated: SceneStates, *, manoeuvres: pd.Series | None = None,
                specs: dict | None = None) -> pd.DataFrame:
    """Score the traffic of one scene: every agent valid at the current time but the ego.

    Args:
        scene: the scene.
        simulated: its K rollouts.
        manoeuvres: track id -> the logged agent's manoeuvre (:func:`agent_manoeuvres`).
        specs: the features (default :data:`~tap_bench.realism.score.WOSAC_2025`).

    Returns:
        One row per evaluated agent and feature: ``scenario_id``, ``track_id``,
        ``object_type``, ``manoeuvre``, ``feature``, ``log_prob_sum``, ``terms``,
        ``simulated_rate`` (Bernoulli features: the share of rollouts in which it happened).
    """
    specs = specs or WOSAC_2025
    window = np.arange(scene.n_steps) > CURRENT_STEP
    evaluated = scene.valid[:, CURRENT_STEP].copy()
    evaluated[scene.ego] = False
    rows = np.flatnonzero(evaluated)
    edges = RoadEdges.from_polylines(scene.road.road_edges)
    first = CURRENT_STEP + 1

    def features(states: SceneStates, k: int) -> dict[str, np.ndarray]:
        return scene_features(scene, states.x[k], states.y[k], states.heading[k],
                              states.valid[k], edges=edges, first=first, selves=rows)

    log_f = features(log_states(scene), 0)
    sim_f: list[dict[str, np.ndarray]] = []
    for k in range(simulated.rollouts):  # rollouts equal to one before (log, constant
        same = next((i for i in range(k) if _same(simulated, i, k)), None)  # velocity) once
        sim_f.append(sim_f[same] if same is not None else features(simulated, k))
    logged, sims = {}, {}
    for name, spec in specs.items():
        if spec.bins:
            lv = log_f[name][rows][:, window].astype(float)
            logged[name] = lv
            sims[name] = np.stack([f[name][rows][:, window].astype(float) for f in sim_f])
        else:
            log_valid = scene.valid[rows][:, window]
            logged[name] = (log_f[name][rows][:, window] & log_valid).any(axis=1)
            sims[name] = np.stack([(f[name][rows][:, window] & log_valid).any(axis=1)
                                   for f in sim_f])
    table = agent_log_likelihoods(logged, sims, specs)
    ids = np.asarray(scene.track_ids)[rows]
    table["scenario_id"] = scene.scenario_id
    table["track_id"] = ids[table["agent"].to_numpy()].astype(str)
    table["object_type"] = np.asarray(scene.object_types)[rows][table["agent"].to_numpy()]
    if manoeuvres is not None:
        table["manoeuvre"] = pd.Series(table["track_id"]).map(manoeuvres).fillna(
            "unlabelled").to_numpy()
    else:
        table["manoeuvre"] = "unlabelled"
    rate = np.full(len(table), np.nan)
    for name, spec in specs.items():
        if not spec.bins:
            at = (table["feature"] == name).to_numpy()
            rate[at] = sims[name].mean(axis=0)[table.loc[at, "agent"].to_numpy()]
    table["simulated_rate"] = rate
    return table[["scenario_id", "track_id", "object_type", "manoeuvre", "feature",
                  "log_prob_sum", "terms", "simulated_rate"]]


def _same(states: SceneStates, i: int, k: int) -> bool:
    """Whether rollouts i and k are the same states."""
    return bool(np.array_equal(states.valid[i], states.valid[k])
                and np.array_equal(states.x[i], states.x[k], equal_nan=True)
                and np.array_equal(states.y[i], states.y[k], equal_nan=True)
                and np.array_equal(states.heading[i], states.heading[k], equal_nan=True))


def agent_manoeuvres(scene: Scene) -> pd.Series:
    """Each logged track's manoeuvre over the simulated window (track id -> label): its
    longest TAP manoeuvre-level turn or merge of at least :data:`MANOEUVRE_MIN` s
    (``Left Turn``, ``Right Turn``, ``Left Merge``, ``Right Merge``); else ``Stopped`` when
    it stands still most of the window; else ``Straight``. Tracks TAP cannot label (under
    1 s of valid steps in the window) are left out."""
    from tap_bench.labelling import tap

    table = scene.table()
    table = table[table["t"] >= (CURRENT_STEP * 0.1) - 1e-6]
    table = table[table["valid"].astype(bool)]
    if table.empty:
        return pd.Series(dtype=object)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        segments = tap(table.drop(columns=[c for c in ("is_ego",) if c in table.columns]),
                       source=f"scenario {scene.scenario_id}").segments("maneuver")
    segments = segments.assign(duration=segments["t_end"] - segments["t_start"],
                               track_id=segments["track_id"].astype(str))
    out = {}
    for track, group in segments.groupby("track_id", sort=False):
        lateral = group[(group["axis"] == "lateral") & (group["label"] != "Straight")
                        & (group["duration"] >= MANOEUVRE_MIN - 1e-9)]
        if len(lateral):
            out[track] = str(lateral.groupby("label")["duration"].sum().idxmax())
            continue
        lon = group[group["axis"] == "longitudinal"]
        stopped = lon.loc[lon["label"] == "Stopped", "duration"].sum()
        out[track] = "Stopped" if stopped > 0.5 * lon["duration"].sum() else "Straight"
    return pd.Series(out, dtype=object)
