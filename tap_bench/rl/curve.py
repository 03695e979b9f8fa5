"""The behaviour-coverage learning curve of an agent in training.

At points of its training the agent, acting greedily, is evaluated on fixed seeds of the
scenario (the scenario itself: 10 Hz, recorded, whatever env it trains on); its egos are
labelled with TAP, and one row of the curve records how well it drives (return, crash rate)
and what it does: the coverage of a reference label set (IDM/MOBIL rollouts on the same
seeds, a WOMD label table, or the SDL vocabulary) and the diversity of its own labels
(Hill numbers: distinct labels and the effective number of labels). Reading the rows in
order shows how the agent's repertoire of behaviours grows, or collapses, as its return
improves.

The curve table, one row per evaluation (:data:`CURVE_COLUMNS`):

======================  ====================================================================
column                  what
======================  ====================================================================
``timesteps``           env steps (decisions) of training before the evaluation
``seconds``             wall time of training and evaluations so far [s]
``train_return``        mean return of the last (up to) 100 training episodes; NaN before one
``episodes``            evaluation episodes run (one per seed)
``return_mean``         mean return of the evaluation episodes
``return_sd``           their standard deviation
``crash_rate``          share of evaluation episodes in which the ego collided
``crash_low/high``      its Wilson score interval (``level``)
``n``                   evaluation episodes whose ego has a label
``coverage`` (+ ``_low``, ``_high``)   share of the reference's labels shown
``weighted_coverage`` (+ ``weighted_low``, ``weighted_high``)   reference weight shown
``n_distinct``          distinct SDL labels of the agent (Hill number q = 0 of the sample)
``diversity`` (+ ``diversity_low``, ``diversity_high``)   effective number of labels, the
                        Hill number q = 1 (exp of the Shannon entropy) of the sample
``completeness``        sample completeness: the estimated share of the agent's label
                        distribution the evaluation has shown
======================  ====================================================================

The intervals are those of the benchmark's measures:
:func:`tap_bench.bench.scores.coverage.coverage`,
:func:`tap_bench.bench.scores.diversity.diversity` (at the sample's own size: every point has the
same seeds) and :func:`tap_bench.stats.intervals.wilson_interval` (crash rate).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd

from tap_bench import sdl
from tap_bench.bench.episodes import ego_labels
from tap_bench.bench.scores.coverage import (
    Reference,
    corpus_reference,
    coverage,
    vocabulary_reference,
)
from tap_bench.bench.scores.diversity import ORDERS, diversity
from tap_bench.errors import ParameterError, did_you_mean
from tap_bench.labelling import tap
from tap_bench.sim.rollout import rollout
from tap_bench.sim.scenario_format import Scenario, parse_seeds
from tap_bench.stats.bootstrap import BootstrapConfig
from tap_bench.stats.intervals import wilson_interval
from tap_bench.tableio import atomic_path, read_table

__all__ = ["CURVE_COLUMNS", "CurveConfig", "GreedyModelPolicy", "coverage_reference",
           "curve_row", "plot_curve"]

CURVE_COLUMNS = ("timesteps", "seconds", "train_return", "episodes", "return_mean",
                 "return_sd", "crash_rate", "crash_low", "crash_high", "n", "coverage",
                 "coverage_low", "coverage_high", "weighted_coverage", "weighted_low",
                 "weighted_high", "n_distinct", "diversity", "diversity_low", "diversity_high",
                 "completeness")
"""Columns of the curve table, in order (see the module docstring)."""


@dataclass(frozen=True)
class CurveConfig:
    """How the learning curve is measured.

    Attributes:
        points: evaluations after the start (at about every ``timesteps / points`` steps),
            plus one of the untrained agent.
        seeds: evaluation seeds (``"500-519"``); keep them apart from the seeds the agent is
            tested on.
        reference: ``"vocabulary"`` (the SDL vocabulary of ``level``), a policy name whose
            rollouts on ``seeds`` are the reference (``"idm"``), or a label or trajectory
            table file (``.parquet``/``.csv``, e.g. WOMD).
        level: SDL level of the labels.
        thresholds: TAP thresholds preset or file.
        level_ci: two-sided level of the intervals.
        n_resamples: draws of the coverage and diversity intervals.
    """

    points: int = 10
    seeds: str = "500-519"
    reference: str = "idm"
    level: str = "maneuver"
    thresholds: str = "paper"
    level_ci: float = 0.95
    n_resamples: int = 1000

    def __post_init__(self) -> None:
        if (isinstance(self.points, bool) or not isinstance(self.points, int)
                or self.points < 1):
            raise ParameterError("points", self.points, "an integer >= 1 (evaluations; "
                                 "tap-bench train --curve-points)")
        if len(parse_seeds(self.seeds, source="curve seeds")) < 2:
            raise ParameterError("seeds", self.seeds, "at least 2 evaluation seeds")
        if self.level not in sdl.LEVELS:
            raise did_you_mean("level", self.level, sdl.LEVELS)

    @property
    def seed_list(self) -> list[int]:
        """The evaluation seeds."""
        return parse_seeds(self.seeds, source="curve seeds")

    def bootstrap(self) -> BootstrapConfig:
        """The :class:`~tap_bench.stats.bootstrap.BootstrapConfig` of the intervals."""
        return BootstrapConfig(n_resamples=self.n_resamples, level=self.level_ci, seed=0)


class GreedyModelPolicy:
    """A Stable-Baselines3 model in memory (one being trained) as a :class:`Policy` that
    acts greedily.

    Unlike :class:`tap_bench.sim.sb3.SB3Policy` it never reseeds the model: SB3's
    ``set_random_seed`` also reseeds the training envs, which an evaluation in the middle of
    training must not do (greedy actions need no randomness).

    Args:
        model: the SB3 model.
        name: the policy name in tables.
        observation: the highway-env observation config the model reads.
    """

    def __init__(self, model: Any, name: str, observation: Mapping[str, Any]) -> None:
        self.model = model
        self.name = name
        self.observation = dict(observation)

    def reset(self, env: gym.Env, *, seed: int) -> None:
        if env.action_space != self.model.action_space:
            raise ValueError(f"policy {self.name!r}: the env's action space {env.action_space} "
                             f"differs from the model's ({self.model.action_space}).")

    def act(self, observation: Any) -> Any:
        action, _ = self.model.predict(observation, deterministic=True)
        return int(action) if np.ndim(action) == 0 else action


def _ego_sdl(trajectories: pd.DataFrame, config: CurveConfig, source: str) -> pd.Series:
    """The ego's SDL label per seed (NA when it has none) of a rollout's trajectories."""
    if trajectories.empty:
        return pd.Series(dtype="string")
    ego = trajectories[trajectories["is_ego"].to_numpy(bool)]
    seeds = ego.drop_duplicates("scenario_id").set_index("scenario_id")["seed"]
    labels = tap(ego, config.thresholds, source=source).labels(config.level)
    table = ego_labels(labels, config.level, source=source)
    sdl = pd.Series(table["sdl"].to_numpy(), index=table["scenario_id"].to_numpy())
    # an ego without a label (shorter than 1 s: a crash at the start) is NA
    return sdl.reindex(seeds.index).set_axis(seeds.to_numpy()).astype("string")


def coverage_reference(config: CurveConfig, scenario: Scenario) -> Reference:
    """The reference of the curve's coverage (:class:`tap_bench.bench.scores.coverage.Reference`).

    ``config.reference`` is ``"vocabulary"``, a policy name (its rollouts on the curve's
    seeds, ego labels) or a label or trajectory table file (every vehicle's labels).

    Raises:
        FileFormatError: the file cannot be read; LabelTableError: it has no labels at the
            level; UnknownNameError: no such policy.
    """
    ref = config.reference
    if ref == "vocabulary":
        return vocabulary_reference(config.level)
    if ref.endswith((".parquet", ".csv", ".csv.gz")):
        table = read_table(ref)
        if "sdl" not in table.columns:
            table = tap(table, config.thresholds, source=ref).labels(config.level)
        return corpus_reference(table, config.level, tracks="vehicles",
                                name=os.path.basename(ref))
    trajectories, _ = rollout(scenario, ref, config.seed_list, progress=False)
    sdl = _ego_sdl(trajectories, config, f"{ref} rollouts on {scenario.name}")
    table = pd.DataFrame({"scenario_id": sdl.index.astype(str), "sdl": sdl.to_numpy(),
                          "track_id": "ego", "is_ego": True})
    return corpus_reference(table, config.level, tracks="ego",
                            name=f"{ref} rollouts on {scenario.name}, seeds {config.seeds}")


def curve_row(policy: Any, scenario: Scenario, reference: Reference, config: CurveConfig, *,
              timesteps: int, seconds: float, train_return: float) -> dict[str, Any]:
    """Evaluate ``policy`` on the curve's seeds of ``scenario`` and return one curve row.

    Args:
        policy: a :class:`Policy` (a :class:`GreedyModelPolicy` during training).
        scenario: the scenario to evaluate on (10 Hz, recorded).
        reference: from :func:`coverage_reference`.
        config: the curve's settings.
        timesteps, seconds, train_return: the training state, copied into the row.

    Returns:
        a dict with the keys :data:`CURVE_COLUMNS`.
    """
    trajectories, episodes = rollout(scenario, policy, config.seed_list, progress=False)
    ok = episodes[episodes["status"] == "ok"]
    if ok.empty:
        raise RuntimeError(f"curve evaluation at {timesteps} steps: every episode failed "
                           f"({episodes['error'].iloc[0]}).")
    sdl = _ego_sdl(trajectories, config, f"{policy.name} at {timesteps} steps")
    boot = config.bootstrap()
    cv = coverage(sdl, reference, config=boot, rng=boot.rng("curve coverage", timesteps))
    dv = diversity(sdl.dropna().to_numpy(), config=boot,
                   rng=boot.rng("curve diversity", timesteps))
    crashes = int(ok["crashed"].sum())
    low, high = wilson_interval(crashes, len(ok), config.level_ci)
    row = {"timesteps": int(timesteps), "seconds": float(seconds),
           "train_return": float(train_return), "episodes": len(ok),
           "return_mean": float(ok["return"].mean()), "return_sd": float(ok["return"].std()),
           "crash_rate": crashes / len(ok), "crash_low": low, "crash_high": high}
    row.update(cv.row())
    q1 = ORDERS.index(1)
    row.update(diversity=float(dv.hill[q1]), diversity_low=float(dv.hill_low[q1]),
               diversity_high=float(dv.hill_high[q1]), completeness=dv.completeness)
    return {k: row[k] for k in CURVE_COLUMNS}


def plot_curve(curve: pd.DataFrame, path: str | os.PathLike, *, title: str = "",
               kept: int | None = None) -> Path:
    """Plot a curve table: return, crash rate and coverage/diversity against timesteps.

    Args:
        curve: the curve table (:data:`CURVE_COLUMNS`).
        path: the ``.png`` to write (atomically).
        title: the figure's title.
        kept: the timesteps of the weights saved, when not the last (a dashed line).
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    x = curve["timesteps"].to_numpy()
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6), layout="constrained")
    ax = axes[0]
    ax.errorbar(x, curve["return_mean"], yerr=curve["return_sd"], marker="o", capsize=3,
                label="evaluation (mean, sd)")
    ax.plot(x, curve["train_return"], "s--", color="0.5", label="training (last 100)")
    ax.set_title("return per episode", fontsize=9)
    ax.legend(fontsize=7)
    ax = axes[1]
    ax.fill_between(x, curve["crash_low"], curve["crash_high"], alpha=0.25, color="C3")
    ax.plot(x, curve["crash_rate"], "o-", color="C3")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title("crash rate (Wilson interval)", fontsize=9)
    ax = axes[2]
    ax.fill_between(x, curve["coverage_low"], curve["coverage_high"], alpha=0.2, color="C0")
    ax.plot(x, curve["coverage"], "o-", color="C0", label="coverage")
    ax.fill_between(x, curve["weighted_low"], curve["weighted_high"], alpha=0.2, color="C1")
    ax.plot(x, curve["weighted_coverage"], "^-", color="C1", label="weighted coverage")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title("coverage of the reference; diversity", fontsize=9)
    twin = ax.twinx()
    twin.fill_between(x, curve["diversity_low"], curve["diversity_high"], alpha=0.15,
                      color="C2")
    twin.plot(x, curve["diversity"], "d:", color="C2", label="effective labels (q = 1)")
    twin.plot(x, curve["n_distinct"], "x:", color="C4", label="distinct labels")
    twin.set_ylim(bottom=0)
    twin.set_ylabel("labels of the agent", fontsize=8)
    lines = ax.get_legend_handles_labels()
    more = twin.get_legend_handles_labels()
    ax.legend(lines[0] + more[0], lines[1] + more[1], fontsize=7, loc="upper left")
    for ax in axes:
        ax.set_xlabel("training steps")
        ax.grid(alpha=0.3)
        if kept is not None:
            ax.axvline(kept, color="0.3", linestyle="--", linewidth=1)
    if kept is not None:
        right = kept > (x.min() + x.max()) / 2  # the note on the side with room
        axes[0].annotate(f"weights kept ({kept} steps)", (kept, 1), xycoords=(
            "data", "axes fraction"), xytext=(-3 if right else 3, -12),
            textcoords="offset points", ha="right" if right else "left", fontsize=7,
            color="0.3")
    if title:
        fig.suptitle(title, fontsize=10, parse_math=False)  # a model name is not math
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, bbox_inches="tight", format="png")
    plt.close(fig)
    return path
