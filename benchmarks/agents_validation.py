"""Choose an agent's design without the held-out scenes: drive policies on validation scenes
(training scenes left out of a selection run's training), as every driver of each scene.

Every vehicle of each scene that drives from the current time to the end
(:func:`tap_bench.rl.heldout.drivers`, the scene's own ego first) is the ego of one episode
per policy (log traffic, the training setting, or ``--traffic idm``: the other vehicles driven
by IDM/MOBIL from their logged states, reactive), so 4 validation scenes give tens of episodes
instead of 4. Prints, per policy: episodes, route progress (mean and interquartile mean over
the episodes where the driver moved), at-fault collisions and off-road (rates), and the
probabilities that the first policy gets further than each other one, and that it collides
at fault less, on the same episode (ties a half); for an agent with a safety layer
(:mod:`tap_bench.sim.womd_safety`) the share of its simulated steps in which the layer
lowered the agent's acceleration (``layer_capped``), made it brake where the agent did
not (``layer_braked``) and capped it for a predicted conflict (``layer_foreseen``, a layer
with ``predicted``); writes every episode to ``--out`` (CSV).
``--pool NAME=P1,P2,...`` adds a row NAME for the episodes of those policies together (an
agent's training seeds), compared episode by episode as each seed is (first: the first
policy is then NAME).
``--intervals`` adds 95% intervals (2,000 resamples, a fixed stream): the first pool's route
progress IQM and at-fault rate over its seeds (rliable's stratified bootstrap, drivers as
tasks, and whole seeds resampled), and, for every policy and for the first's difference from
each, over the scenes (whole scenes with all their drivers and seeds resampled, the same draws
for every policy, widened by sqrt(G / (G - 1)) for G scenes): whether the scenes driven
separate the policies.
``--episodes CSV ...`` reads the episodes of earlier runs (their ``--out`` tables, joined)
in place of driving (``--womd`` is then not needed, ``--scenes`` keeps some scenes only).
``--cross NAME=A0,A1+B0,B1`` pools a cross-fitted agent: each fold (``+`` between folds,
its models by ``,``) drove only scenes its definitions record as held out, and the folds
together drove every driver the other policies drove; run s of NAME is every fold's model
of training seed s (the definitions' ``seed``), relabelled ``NAME#s``, and NAME is the first
pool (:func:`cross_fitted`); its seed intervals resample seeds within each fold.
``--layer JSON`` drives every policy of ``--policies`` that drives with a safety layer (a
trained agent whose action config has ``safety_layer``) with this one in its place (a
mapping of :class:`tap_bench.sim.womd_safety.SafetyLayer`'s fields, ``true`` or ``false``);
the other policies drive as defined, and each episode's ``layer`` column says which layer
its ego drove with (compact JSON; blank: none of its own).

Usage: python benchmarks/agents_validation.py --womd FILES --scenes 2,5,10,14
       --policies sel-all.zip sel-sdc.zip lane-keeping random [--out eps.csv]
       [--intervals] [--traffic idm]
       [--layer '{"predicted": true, "lanes": true, "tolerance": 0.5, "hold": true}']
       [--pool ppo-womd=ppo-womd-grid-seed0,ppo-womd-grid-seed1,ppo-womd-grid-seed2]
       python benchmarks/agents_validation.py --episodes folda.csv foldb.csv
       --policies lane-keeping random idm --intervals
       --cross ppo-womd-xfit=ppo-womd-grid-seed0,ppo-womd-grid-seed1+ppo-womd-grid-foldb-seed0,ppo-womd-grid-foldb-seed1
"""  # noqa: E501

from __future__ import annotations

import argparse
import json
import time
import warnings
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from machine import report

from tap_bench.errors import ParameterError
from tap_bench.rl.heldout import drivers
from tap_bench.sim.policies import Policy, get_definition, load_policy
from tap_bench.sim.rollout import policy_overrides, run_episode
from tap_bench.sim.womd_env import WomdEnv
from tap_bench.sim.womd_safety import safety_layer
from tap_bench.sim.womd_scene import WomdScenes
from tap_bench.stats.aggregate import BATCHED, Interval, iqm, mean_score, stratified_bootstrap
from tap_bench.stats.bootstrap import cluster_factor, named_rng


def policy_env(scenes: WomdScenes, policy: Policy) -> WomdEnv:
    """The env ``policy`` drives, configured as a bench run configures it
    (:func:`tap_bench.sim.rollout.policy_overrides`: the observation it reads, its own
    action config, a safety layer, if any)."""
    return WomdEnv(scenes.with_overrides(policy_overrides(policy)), record=False)


def parse_layer(text: str) -> Any:
    """The safety layer ``--layer`` asks for: ``text`` as JSON, ``true``, ``false`` or a
    mapping of :class:`~tap_bench.sim.womd_safety.SafetyLayer`'s fields, checked as a
    policy's action config is (:func:`~tap_bench.sim.womd_safety.safety_layer`).

    Raises:
        ValueError: not JSON, or not a layer (says why, with the fields it takes).
    """
    try:
        setting = json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(f"--layer {text}: not JSON ({error}); write true, false or a "
                         'mapping such as \'{"predicted": true, "lanes": true, '
                         '"tolerance": 0.5, "hold": true}\'') from None
    try:
        safety_layer(setting)
    except ParameterError as error:
        raise ValueError(f"--layer {text}: {error}") from None
    return setting


def layered(policies: list[str]) -> list[str]:
    """Those of ``policies`` whose definitions drive with a safety layer (their action
    config has ``safety_layer``): the ones ``--layer`` changes."""
    out = []
    for name in policies:
        action = get_definition(name).params.get("action")
        if isinstance(action, Mapping) and "safety_layer" in action:
            out.append(name)
    return out


def with_layer(policy: Policy, layer: Any) -> bool:
    """Make ``policy`` drive with the safety layer ``layer`` (a ``safety_layer`` setting)
    in place of its own, if it drives with one; returns whether it does."""
    action = getattr(policy, "action", None)
    if not isinstance(action, Mapping) or "safety_layer" not in action:
        return False
    policy.action = {**action, "safety_layer": layer}
    return True


_OWN = object()  # episodes(): every policy drives with its own layer


def episodes(files: list[str], scenes: list[int], policies: list[str],
             layer: Any = _OWN, traffic: str = "log") -> pd.DataFrame:
    """One row per (policy, scene, driver): the episode's measures, and the scene's file and
    record (``scene_ref``, as a policy definition's ``held_out_refs`` names it); with
    ``layer`` (a ``safety_layer`` setting) the policies that drive with a safety layer drive
    with that one (:func:`with_layer`), and ``layer`` says so (compact JSON). ``traffic``
    (``"log"`` or ``"idm"``, :class:`~tap_bench.sim.womd_scene.WomdScenes`) is what the other
    vehicles do, and each row's ``traffic`` says it."""
    scenes_ = WomdScenes(tuple(files), traffic)
    refs = scenes_.catalog()
    rows = []
    for name in policies:
        policy = load_policy(name)
        changed = layer is not _OWN and with_layer(policy, layer)
        env = policy_env(scenes_, policy)
        for i in scenes:
            for track in drivers(env.scene_at(i)):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    _, row = run_episode(env, policy, i, record=False,
                                         options={"scene": i, "ego": track})
                layer_ = getattr(env.unwrapped.vehicle, "safety", None)
                rows.append({"policy": name, "scene": i, "scene_ref": str(refs[i]),
                             "track": track, "traffic": traffic,
                             **{k: row.get(k) for k in (
                                 "status", "route_progress", "crashed", "crash_at_fault",
                                 "off_road", "return", "length")},
                             **({"layer": json.dumps(layer, sort_keys=True,
                                                     separators=(",", ":"))}
                                if changed else {}),
                             # the agent's safety layer: simulated steps it judged, lowered
                             # the policy's acceleration in, made it brake in
                             **({"layer_steps": layer_.steps, "layer_capped": layer_.capped,
                                 "layer_braked": layer_.braked,
                                 "layer_foreseen": layer_.foreseen}
                                if layer_ is not None else {})})
    return pd.DataFrame(rows)


def read_episodes(paths: list[str], scenes: list[int] | None = None) -> pd.DataFrame:
    """The episode tables ``paths`` (this script's ``--out``) joined, on ``scenes`` only if
    given; refuses a (policy, scene, track) episode found twice, tables of different traffic
    (a table without a ``traffic`` column is log traffic's, as every table before it), and an
    episode that ended as episodes do (status ok) without its ``crash_at_fault`` or
    ``off_road`` (a blank would read as True)."""
    tables, traffics = [], {}
    for path in paths:
        table = pd.read_csv(path, dtype={"track": str})
        kinds = table["traffic"].dropna().unique() if "traffic" in table else ["log"]
        for kind in kinds:
            traffics.setdefault(str(kind), path)
        if len(traffics) > 1:
            raise ValueError(
                f"{path}: episodes of {' and '.join(sorted(traffics))} traffic in one verdict "
                f"({', '.join(f'{k}: {v}' for k, v in sorted(traffics.items()))}); the other "
                "vehicles differ, so the episodes are not paired: read each traffic's tables "
                "on their own")
        ok = table["status"] == "ok"
        for column in ("crash_at_fault", "off_road"):
            if column not in table:
                raise ValueError(f"{path}: no column {column}")
            blank = ok & table[column].isna()
            if blank.any():
                row = int(np.flatnonzero(blank.to_numpy())[0])
                raise ValueError(
                    f"{path}: row {row} (line {row + 2}), an episode with status ok "
                    f"({table['policy'].iloc[row]}, scene {table['scene'].iloc[row]}, track "
                    f"{table['track'].iloc[row]}), has no {column}; a blank is not False: "
                    "drive that episode again or mark the row's status")
        tables.append(table)
    eps = pd.concat(tables, ignore_index=True)
    if scenes is not None:
        eps = eps[eps["scene"].isin(scenes)].reset_index(drop=True)
    twice = eps.duplicated(["policy", "scene", "track"])
    if twice.any():
        first = eps[twice].iloc[0]
        raise ValueError(f"{first['policy']} drove scene {first['scene']}, track "
                         f"{first['track']} more than once in {paths}")
    return eps


@dataclass(frozen=True)
class Trained:
    """What a trained model's definition records of its training (:func:`trained`).

    Attributes:
        seed: the training seed (``params.seed``).
        train: scene indexes trained on (``train_scenes``); None: not recorded.
        held_out: scene indexes held out (``held_out_scenes``); None: not recorded.
        held_out_refs: the held-out scenes' ``"file record k"`` (``held_out_refs``, in
            ``held_out``'s order); None: not recorded.
    """

    seed: int
    train: tuple[int, ...] | None
    held_out: tuple[int, ...] | None
    held_out_refs: tuple[str, ...] | None = None

    def may_drive(self, scene: int) -> bool:
        """Whether the model never trained on ``scene``: not among its training scenes and,
        where its held-out scenes are recorded, among them."""
        return ((self.train is None or scene not in self.train)
                and (self.held_out is None or scene in self.held_out))


def trained(policy: str) -> Trained:
    """The training record of ``policy``'s definition.

    Raises:
        ValueError: the definition records no seed, or neither its held-out nor its
            training scenes (its training scenes are then unknown).
    """
    params = get_definition(policy).params
    train, held = params.get("train_scenes"), params.get("held_out_scenes")
    if train is None and held is None:
        raise ValueError(
            f"{policy}: its definition records neither held_out_scenes nor train_scenes, so "
            "the scenes it trained on are unknown; cross-fit models trained on recorded "
            "scenes with --hold-out (tap-bench train --env womd --hold-out SCENES), whose "
            "definitions record both")
    if params.get("seed") is None:
        raise ValueError(f"{policy}: its definition records no training seed (params "
                         "seed), by which the folds' runs are paired; retrain with --seed")
    refs = params.get("held_out_refs")
    return Trained(int(params["seed"]), None if train is None else tuple(train),
                   None if held is None else tuple(held), None if refs is None else tuple(refs))


def _ref_key(ref: str) -> tuple[str, str]:
    """A scene ref (``"dir/file record k"``, or a one-scene file) by file name and record,
    so the same scene named from another directory matches."""
    path, _, record = str(ref).partition(" record ")
    return Path(path).name, record


def cross_fitted(eps: pd.DataFrame, name: str, folds: list[list[str]],
                 models: Mapping[str, Trained], baselines: list[str] | None = None
                 ) -> tuple[pd.DataFrame, list[str]]:
    """``eps`` with the runs of a cross-fitted agent added, and the run names: run s (policy
    ``name#s``) is the episodes of every fold's model of training seed s (``models``: each
    policy's :class:`Trained`).

    Refuses: an empty ``name``, fewer than two folds, a model named twice, a model not in
    ``eps``, folds whose seeds differ; a fold whose models did not all drive the same drivers;
    a model on a scene it may have trained on (:meth:`Trained.may_drive`; where ``eps`` has
    ``scene_ref``, also a scene whose ref is not the one the model held out as that index);
    a scene driven by two folds; and folds that together did not drive exactly the drivers
    (scene, track) that ``baselines`` (default: every other policy of ``eps``) drove.
    """
    where = f"--cross {name}"
    if not name:
        raise ValueError("--cross: the cross-fitted agent needs a name (NAME=A0,A1+B0,B1)")
    if len(folds) < 2:
        raise ValueError(f"{where}: {len(folds)} fold; cross-fitting pools two or more "
                         "(folds by +)")
    flat = [p for fold in folds for p in fold]
    twice = sorted({p for p in flat if flat.count(p) > 1})
    if twice:
        raise ValueError(f"{where}: {twice} named more than once; each model is one seed "
                         "of one fold")
    absent = sorted(set(flat) - set(eps["policy"]))
    if absent:
        raise ValueError(f"{where}: {absent} not in the episode table")
    unknown = sorted(set(flat) - set(models))
    if unknown:
        raise ValueError(f"{where}: no training record for {unknown}")
    by_seed = [{models[p].seed: p for p in fold} for fold in folds]
    seeds = [sorted(models[p].seed for p in fold) for fold in folds]
    if any(len(set(s)) != len(s) or s != seeds[0] for s in seeds):
        raise ValueError(f"{where}: the folds' training seeds {seeds} differ (or repeat "
                         "within a fold); every fold needs one model of each seed")
    keys = ["scene", "track"]
    drove = {p: set(map(tuple, eps.loc[eps["policy"] == p, keys].to_numpy().tolist()))
             for p in flat}
    seen: dict[int, int] = {}
    for f, fold in enumerate(folds):
        driven = [drove[p] for p in fold]
        if any(d != driven[0] for d in driven):
            raise ValueError(f"{where}: the seeds of fold {f} ({fold}) did not all drive the "
                             "same scenes: "
                             f"{[sorted({s for s, _ in d}) for d in driven]}")
        for policy in fold:
            model = models[policy]
            rows = eps[eps["policy"] == policy]
            bad = sorted(int(s) for s in set(rows["scene"]) if not model.may_drive(int(s)))
            if bad:
                raise ValueError(f"{where}: {policy} drove scenes it trained on: {bad} (its "
                                 f"definition: train_scenes {list(model.train or [])}, "
                                 f"held_out_scenes {list(model.held_out or [])})")
            if "scene_ref" in rows and model.held_out is not None and model.held_out_refs:
                held = dict(zip(model.held_out, model.held_out_refs, strict=True))
                for scene, ref in rows[["scene", "scene_ref"]].drop_duplicates().to_numpy():
                    if pd.notna(ref) and _ref_key(ref) != _ref_key(held[int(scene)]):
                        raise ValueError(
                            f"{where}: the table's scene {scene} is {ref}, but {policy} held "
                            f"out {held[int(scene)]} as scene {scene}: the table was driven "
                            "on the files in another order than the model's training")
        scenes = {int(s) for s, _ in driven[0]}
        both = {s: seen[s] for s in scenes if s in seen}
        if both:
            raise ValueError(f"{where}: scenes {sorted(both)} driven by folds "
                             f"{sorted(set(both.values()))} and {f}")
        seen.update(dict.fromkeys(scenes, f))
    others = eps[eps["policy"].isin(baselines) if baselines is not None
                 else ~eps["policy"].isin(flat)]
    if len(others):
        expected = set(map(tuple, others[keys].to_numpy().tolist()))
        covered = set().union(*(drove[fold[0]] for fold in folds))
        if covered != expected:
            missing, extra = sorted(expected - covered), sorted(covered - expected)
            raise ValueError(f"{where}: the folds did not drive the drivers the other "
                             f"policies drove: {len(missing)} (scene, track) not driven by "
                             f"any fold {missing[:5]}, {len(extra)} driven by a fold only "
                             f"{extra[:5]}")
    runs = [f"{name}#{s}" for s in seeds[0]]
    added = [eps[eps["policy"].isin([fold[s] for fold in by_seed])].assign(policy=run)
             for s, run in zip(seeds[0], runs, strict=True)]
    return pd.concat([eps, *added], ignore_index=True), runs


def _p_better(first: pd.DataFrame, mine: pd.DataFrame, column: str, sign: float) -> float:
    """P(a run of ``first`` beats one of ``mine`` on the same episode): ``sign`` * value
    higher, ties a half; every pair of their runs of an episode (several seeds each)."""
    pairs = first[["scene", "track", column]].merge(
        mine[["scene", "track", column]], on=["scene", "track"], suffixes=("_a", "_b"))
    a = sign * pairs[f"{column}_a"].astype(float)
    b = sign * pairs[f"{column}_b"].astype(float)
    keep = a.notna() & b.notna()
    a, b = a[keep], b[keep]
    return float(((a > b) + 0.5 * (a == b)).mean()) if len(a) else float("nan")


def summary(eps: pd.DataFrame, policies: list[str],
            pools: dict[str, list[str]] | None = None) -> pd.DataFrame:
    """Per policy (and per pool of policies): the figures printed (see the module
    docstring); the first of ``pools`` (else of ``policies``) is compared with the others."""
    ok = _judged(eps)
    groups = {**{name: [name] for name in policies}, **(pools or {})}
    lead = next(iter(pools)) if pools else policies[0]
    first = ok[ok["policy"].isin(groups[lead])]
    out = []
    for name, members in groups.items():
        rows = ok[ok["policy"].isin(members)]
        moved = rows["route_progress"].dropna().to_numpy(float)
        layer = {}
        if "layer_steps" in rows and rows["layer_steps"].notna().any():
            steps = rows["layer_steps"].sum()
            layer = {"layer_capped": float(rows["layer_capped"].sum() / steps),
                     "layer_braked": float(rows["layer_braked"].sum() / steps),
                     "layer_foreseen": float(rows["layer_foreseen"].sum() / steps)}
        out.append({"policy": name, "episodes": len(rows), **layer,
                    # nan where no driver moved (no route progress to average)
                    "progress_mean": float(moved.mean()) if len(moved) else float("nan"),
                    "progress_iqm": float(iqm(moved)) if len(moved) else float("nan"),
                    "at_fault": float(rows["at_fault"].mean()),
                    "at_fault_n": int(rows["at_fault"].sum()),
                    "off_road": float(rows["off_road"].astype(bool).mean()),
                    "off_road_n": int(rows["off_road"].astype(bool).sum()),
                    f"P({lead} further)": _p_better(first, rows, "route_progress", 1.0),
                    f"P({lead} fewer at fault)": _p_better(first, rows, "at_fault", -1.0)})
    return pd.DataFrame(out)


def _judged(eps: pd.DataFrame) -> pd.DataFrame:
    """The episodes that ended as episodes do (status ok), with ``at_fault`` as 0/1."""
    ok = eps[eps["status"] == "ok"].copy()
    ok["at_fault"] = ok["crash_at_fault"].astype(bool).astype(float)
    return ok


def seed_intervals(eps: pd.DataFrame, members: list[str], *,
                   strata: list[Collection[int]] | None = None, n_resamples: int = 2000,
                   level: float = 0.95, seed: int = 0) -> dict[str, float]:
    """An agent's route progress IQM and at-fault rate over its seeds ``members`` (runs) x
    the drivers every seed drove (tasks; for progress, those who moved in every seed's
    episode), with percentile intervals at ``level``: ``*_task`` rliable's stratified
    bootstrap, ``*_run`` whole seeds resampled (:func:`stratified_bootstrap`).

    ``strata`` (a cross-fitted agent: each fold's scenes) resamples the seeds within each
    fold on its own: a draw takes, for each fold's drivers, that many of the fold's seeds
    with replacement, independently of the other folds (:func:`_fold_run_bootstrap`), so
    the interval does not depend on which seed of one fold a run pairs with which of
    another."""
    ok = _judged(eps)
    ok = ok[ok["policy"].isin(members)]
    out: dict[str, float] = {}
    for column, statistic, key in (("route_progress", iqm, "iqm"),
                                   ("at_fault", mean_score, "at_fault")):
        table = ok.pivot_table(index=["scene", "track"], columns="policy", values=column,
                               aggfunc="first", dropna=False)
        table = table.reindex(columns=members).dropna()
        scores = table.to_numpy(float).T
        for unit in ("task", "run"):
            rng = named_rng(seed, "agents_validation", key, unit)
            if unit == "run" and strata is not None and len(strata) > 1:
                scene = table.index.get_level_values("scene").to_numpy()
                blocks = [np.flatnonzero(np.isin(scene, list(s))) for s in strata]
                interval = _fold_run_bootstrap(scores, statistic, blocks, rng=rng,
                                               level=level, n_resamples=n_resamples)
            else:
                interval = stratified_bootstrap(scores, statistic, rng=rng, level=level,
                                                n_resamples=n_resamples, unit=unit)
            out[key] = interval.estimate
            out[f"{key}_low_{unit}"], out[f"{key}_high_{unit}"] = interval.low, interval.high
    return out


def _fold_run_bootstrap(scores: np.ndarray, statistic: Callable[[np.ndarray], float],
                        blocks: list[np.ndarray], *, rng: np.random.Generator, level: float,
                        n_resamples: int) -> Interval:
    """:func:`stratified_bootstrap`'s whole-run resampling of ``scores`` (runs x tasks),
    stratified by fold: the task columns of each of ``blocks`` get runs drawn on their own
    (every fold's seeds resampled independently); the draws widened by sqrt(n / (n - 1))
    for n runs and, for a mean, kept within the scores' range."""
    n_runs, n_tasks = scores.shape
    covered = np.sort(np.concatenate(blocks)) if blocks else np.array([], int)
    if not np.array_equal(covered, np.arange(n_tasks)):
        raise ValueError("the folds' scenes do not split the drivers into one fold each")
    rows = np.empty((n_resamples, n_runs, n_tasks), dtype=int)
    for block in blocks:
        rows[:, :, block] = rng.integers(0, n_runs, size=(n_resamples, n_runs, 1))
    samples = scores[rows, np.arange(n_tasks)]
    if statistic in BATCHED:
        boot = np.asarray(statistic(samples), dtype=float)
    else:
        boot = np.array([statistic(sample) for sample in samples], dtype=float)
    estimate = float(statistic(scores))
    factor = cluster_factor(n_runs)
    spread = boot if not np.isfinite(factor) else estimate + factor * (boot - estimate)
    if statistic in BATCHED:
        spread = np.clip(spread, scores.min(), scores.max())
    alpha = (1 - level) / 2
    low, high = np.quantile(spread, [alpha, 1 - alpha])
    return Interval(estimate, float(low), float(high), level)


def scene_intervals(eps: pd.DataFrame, groups: dict[str, list[str]], lead: str, *,
                    n_resamples: int = 2000, level: float = 0.95,
                    seed: int = 0) -> pd.DataFrame:
    """Per group of ``groups`` (name: its policies): route progress IQM (episodes where the
    driver moved) and at-fault rate with percentile intervals at ``level`` over the scenes,
    and ``lead``'s difference from it (``d_iqm``: lead's IQM less the group's; ``d_at_fault``
    likewise) with its interval. Every resample draws G of the G scenes with replacement,
    each with all its drivers and all seeds, the same draws for every group (paired); the
    draws are widened about the estimate by sqrt(G / (G - 1)), and an at-fault rate's
    interval is kept within [0, 1]."""
    ok = _judged(eps)
    scenes = sorted(ok["scene"].unique())
    g = len(scenes)
    draws = named_rng(seed, "agents_validation", "scenes").integers(0, g, (n_resamples, g))

    def figures(rows: pd.DataFrame) -> tuple[float, float, np.ndarray, np.ndarray]:
        by = {s: rows[rows["scene"] == s] for s in scenes}
        prog = [by[s]["route_progress"].dropna().to_numpy(float) for s in scenes]
        fault = [by[s]["at_fault"].to_numpy(float) for s in scenes]
        boot_iqm, boot_fault = np.empty(n_resamples), np.empty(n_resamples)
        for k, draw in enumerate(draws):
            p = np.concatenate([prog[i] for i in draw])
            f = np.concatenate([fault[i] for i in draw])
            boot_iqm[k] = iqm(p) if len(p) else np.nan
            boot_fault[k] = f.mean() if len(f) else np.nan
        return (float(iqm(np.concatenate(prog))), float(np.concatenate(fault).mean()),
                boot_iqm, boot_fault)

    def interval(estimate: float, boot: np.ndarray, rate: bool = False
                 ) -> tuple[float, float]:
        boot = estimate + cluster_factor(g) * (boot[np.isfinite(boot)] - estimate)
        low, high = np.quantile(boot, [(1 - level) / 2, (1 + level) / 2])
        if rate:  # the widening can carry a rate's draws past 0 or 1, which no rate is
            low, high = max(low, 0.0), min(high, 1.0)
        return float(low), float(high)

    done = {name: figures(ok[ok["policy"].isin(members)]) for name, members in groups.items()}
    lead_iqm, lead_fault, lead_boot_iqm, lead_boot_fault = done[lead]
    rows = []
    for name, (est_iqm, est_fault, boot_iqm, boot_fault) in done.items():
        row = {"policy": name, "iqm": est_iqm}
        row["iqm_low"], row["iqm_high"] = interval(est_iqm, boot_iqm)
        row["at_fault"] = est_fault
        row["at_fault_low"], row["at_fault_high"] = interval(est_fault, boot_fault,
                                                             rate=True)
        if name != lead:
            row["d_iqm"] = lead_iqm - est_iqm
            row["d_iqm_low"], row["d_iqm_high"] = interval(row["d_iqm"],
                                                           lead_boot_iqm - boot_iqm)
            row["d_at_fault"] = lead_fault - est_fault
            row["d_at_fault_low"], row["d_at_fault_high"] = interval(
                row["d_at_fault"], lead_boot_fault - boot_fault)
        rows.append(row)
    return pd.DataFrame(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--womd", nargs="+")
    parser.add_argument("--scenes", help="validation scene indexes, 2,5,10 (with "
                        "--episodes: all the tables' scenes if not given)")
    parser.add_argument("--policies", nargs="+", required=True)
    parser.add_argument("--episodes", nargs="+", metavar="CSV",
                        help="read these runs' episode tables (--out) instead of driving")
    parser.add_argument("--cross", nargs="+", default=[], metavar="NAME=A0,A1+B0,B1",
                        help="a cross-fitted agent: folds by +, each fold's seeds by ,")
    parser.add_argument("--out", help="write the episodes there (CSV)")
    parser.add_argument("--pool", nargs="+", default=[], metavar="NAME=P1,P2",
                        help="a row for the episodes of several policies together")
    parser.add_argument("--layer", metavar="JSON",
                        help="drive the policies that drive with a safety layer with this "
                        "one instead (true, false or a mapping of the layer's fields)")
    parser.add_argument("--traffic", choices=["log", "idm"], default="log",
                        help="the other vehicles replay the log (default) or are driven by "
                        "IDM/MOBIL from their logged states (reactive)")
    parser.add_argument("--intervals", action="store_true",
                        help="95%% intervals over the first pool's seeds and over the scenes")
    args = parser.parse_args()
    if not args.episodes and not (args.womd and args.scenes):
        parser.error("give --womd and --scenes to drive, or --episodes to read runs")
    scenes = [int(s) for s in args.scenes.split(",")] if args.scenes else None
    layer = _OWN
    if args.episodes and args.traffic != "log":
        parser.error("--traffic drives with other traffic: it needs --womd and --scenes, not "
                     "--episodes (the tables' traffic column says what each episode drove in)")
    if args.layer is not None:
        if args.episodes:
            parser.error("--layer drives with another safety layer: it needs --womd and "
                         "--scenes, not --episodes (the tables' layer column says what "
                         "each episode drove with)")
        try:
            layer = parse_layer(args.layer)
        except ValueError as error:
            parser.error(str(error))
        if not layered(args.policies):
            parser.error(f"--layer: none of --policies {args.policies} drives with a safety "
                         "layer (a trained agent whose action config has safety_layer)")
    pools = {}
    for item in args.pool:
        name, _, members = item.partition("=")
        pools[name] = members.split(",")
        unknown = set(pools[name]) - set(args.policies)
        if not name or unknown:
            parser.error(f"--pool {item}: write NAME=P1,P2 with policies of --policies "
                         f"(not in them: {sorted(unknown)})")
    crosses = {}
    for item in args.cross:
        name, eq, spec = item.partition("=")
        folds = [fold.split(",") for fold in spec.split("+")]
        if not eq or not name or len(folds) < 2 or not all(all(fold) for fold in folds):
            parser.error(f"--cross {item}: write NAME=A0,A1+B0,B1 (a name, then two or more "
                         "folds by +, each fold's models by ,)")
        crosses[name] = folds
    start, cpu = time.perf_counter(), time.process_time()
    if args.episodes:
        eps = read_episodes(args.episodes, scenes)
        scenes = sorted(int(s) for s in eps["scene"].unique())
        missing = set(args.policies) - set(eps["policy"])
        if missing:
            parser.error(f"--policies {sorted(missing)} not in the tables {args.episodes}")
    else:
        eps = episodes(args.womd, scenes, args.policies, layer, args.traffic)
    judged, runs, crossed, strata = eps, [], {}, {}
    for name, folds in crosses.items():
        flat = [p for fold in folds for p in fold]
        absent = sorted(set(flat) - set(eps["policy"]))
        if absent:
            parser.error(f"--cross {name}: {absent} not in the tables --episodes read "
                         f"({', '.join(args.episodes)})" if args.episodes else
                         f"--cross {name}: {absent} not among the --policies driven")
        models = {p: trained(p) for p in flat}
        judged, named = cross_fitted(judged, name, folds, models,
                                     [p for p in args.policies if p not in flat])
        crossed[name] = named
        strata[name] = [sorted(set(eps.loc[eps["policy"] == fold[0], "scene"]))
                        for fold in folds]
        runs += named
    pools = {**crossed, **pools}
    table = summary(judged, args.policies + runs, pools)
    with pd.option_context("display.width", 200, "display.max_columns", 20):
        print(table.round(3).to_string(index=False))
    extra = {}
    if args.intervals:
        groups = {**pools, **{name: [name] for name in args.policies}}
        lead = next(iter(pools)) if pools else args.policies[0]
        seeds = seed_intervals(judged, groups[lead], strata=strata.get(lead))
        scenes_table = scene_intervals(judged, groups, lead)
        with pd.option_context("display.width", 250, "display.max_columns", 20):
            print(f"{lead} over its seeds:", {k: round(v, 3) for k, v in seeds.items()})
            print(f"over the {len(scenes)} scenes ({lead}'s differences from each: d_):")
            print(scenes_table.round(3).to_string(index=False))
        extra = {"seed_intervals": seeds,
                 "scene_intervals": scenes_table.replace({np.nan: None}).round(4)
                 .to_dict("records")}
    if args.out:
        eps.to_csv(args.out, index=False)
    report("agents_validation", {**extra,
        "scenes": scenes, "episodes": len(eps), "wall_s": round(time.perf_counter() - start, 1),
        "cpu_s": round(time.process_time() - cpu, 1),
        "summary": table.replace({np.nan: None}).round(4).to_dict("records")})


if __name__ == "__main__":
    main()
