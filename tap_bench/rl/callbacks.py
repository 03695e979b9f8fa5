"""A Stable-Baselines3 callback that records the behaviour-coverage learning curve.

This module imports Stable-Baselines3: import it only where SB3 is installed.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import pandas as pd
from stable_baselines3.common.callbacks import BaseCallback

from tap_bench.errors import ParameterError
from tap_bench.rl.curve import CURVE_COLUMNS, CurveConfig, GreedyModelPolicy, curve_row
from tap_bench.sim.scenario_format import Scenario

__all__ = ["CoverageCallback", "EpisodesCounted", "StepsAnnounced"]


class CoverageCallback(BaseCallback):
    """Evaluates the agent at the start of training, every ``every`` env steps and at the
    end, and records one row of the learning curve each time (:mod:`tap_bench.rl.curve`):
    greedy episodes on the curve's seeds of ``scenario`` (10 Hz, recorded, whatever env the
    agent trains on), their return and crash rate, the coverage of ``reference`` by the
    egos' labels and the labels' diversity.

    Each row also goes to SB3's logger as ``tap/coverage``, ``tap/weighted_coverage``,
    ``tap/diversity``, ``tap/distinct_labels``, ``tap/crash_rate`` and
    ``tap/eval_return``.

    Args:
        scenario: the scenario to evaluate on.
        reference: the coverage reference
            (:func:`tap_bench.rl.curve.coverage_reference`).
        config: the curve's settings (seeds, level, thresholds, intervals).
        every: env steps between evaluations (counted over all training envs).
        until: no evaluation during training from this many steps on (the training's
            length): the end of training has its own, of the weights as saved, after the
            last update. None: evaluate whenever ``every`` steps have passed.
        observation: the highway-env observation config the agent reads.
        name: the agent's name in the rollouts.
        keep_best: also keep a copy of the policy's weights at the evaluation with the
            highest mean return (the first of equal ones), to save instead of the last.
        announce: called with a line before and after each evaluation (which one, at how
            many steps, how long it took and its figures), terminal or not.

    Attributes:
        rows: the curve so far, one dict per evaluation (:attr:`curve` as a table).
        eval_seconds: wall time of each evaluation [s].
        best: the kept evaluation's row (None without ``keep_best`` or before one).
        best_weights: the policy's ``state_dict`` at that evaluation.
    """

    def __init__(self, scenario: Scenario, reference: Any, config: CurveConfig, *,
                 every: int, observation: Mapping[str, Any], name: str = "agent",
                 keep_best: bool = False, until: int | None = None,
                 verbose: int = 0, announce: Callable[[str], None] | None = None) -> None:
        super().__init__(verbose)
        if isinstance(every, bool) or not isinstance(every, int) or every < 1:
            raise ParameterError("every", every, "an integer >= 1 (env steps)")
        self.scenario = scenario
        self.reference = reference
        self.config = config
        self.every = every
        self.observation = dict(observation)
        self.name = name
        self.rows: list[dict[str, Any]] = []
        self.eval_seconds: list[float] = []
        self.keep_best = keep_best
        self.until = until
        self.best: dict[str, Any] | None = None
        self.best_weights: dict[str, Any] | None = None
        self._next = 0
        self._start = 0.0
        self.announce = announce
        # evaluations: the untrained agent, ceil(until / every) - 1 during training, the end
        self._planned = 1 + (-(-until // every) if until is not None else 0)

    @property
    def curve(self) -> pd.DataFrame:
        """The curve table (:data:`tap_bench.rl.curve.CURVE_COLUMNS`)."""
        return pd.DataFrame(self.rows, columns=list(CURVE_COLUMNS))

    @property
    def coverage(self) -> float | None:
        """The coverage of the last evaluation (None before one)."""
        return self.rows[-1]["coverage"] if self.rows else None

    def _on_training_start(self) -> None:
        self._start = time.perf_counter()
        self._evaluate()
        self._next = self.every

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next and (self.until is None
                                                 or self.num_timesteps < self.until):
            self._evaluate()
            # the next multiple of `every`: envs add several steps at a time, and drifting
            # from the grid would squeeze an extra evaluation in before the last one
            self._next = self.every * (self.num_timesteps // self.every + 1)
        return True

    def _on_training_end(self) -> None:
        if not self.rows or self.rows[-1]["timesteps"] != self.num_timesteps:
            self._evaluate()

    def _evaluate(self) -> None:
        began = time.perf_counter()
        if self.announce is not None:
            self.announce(f"learning curve: evaluation {len(self.rows) + 1} of "
                          f"{max(self._planned, len(self.rows) + 1)} at {self.num_timesteps} "
                          f"steps ({len(self.config.seed_list)} episodes) ...")
        buffer = self.model.ep_info_buffer
        train_return = float(np.mean([e["r"] for e in buffer])) if buffer else float("nan")
        policy = GreedyModelPolicy(self.model, self.name, self.observation)
        row = curve_row(policy, self.scenario, self.reference, self.config,
                        timesteps=self.num_timesteps,
                        seconds=time.perf_counter() - self._start, train_return=train_return)
        self.rows.append(row)
        if self.keep_best and (self.best is None
                               or row["return_mean"] > self.best["return_mean"]):
            self.best = row
            self.best_weights = copy.deepcopy(self.model.policy.state_dict())
        self.eval_seconds.append(time.perf_counter() - began)
        for key, value in (("coverage", row["coverage"]),
                           ("weighted_coverage", row["weighted_coverage"]),
                           ("diversity", row["diversity"]),
                           ("distinct_labels", row["n_distinct"]),
                           ("crash_rate", row["crash_rate"]),
                           ("eval_return", row["return_mean"])):
            self.logger.record(f"tap/{key}", value)
        self.logger.dump(self.num_timesteps)  # as SB3's EvalCallback: one log row per point
        line = (f"{self.num_timesteps} steps: return {row['return_mean']:.2f}, crash rate "
                f"{row['crash_rate']:.2f}, coverage {row['coverage']:.2f}, diversity "
                f"{row['diversity']:.2f} labels")
        if self.announce is not None:
            self.announce(f"learning curve: {line} ({self.eval_seconds[-1]:.0f} s)")
        elif self.verbose:
            print(f"{self.num_timesteps} steps: return {row['return_mean']:.2f}, crash rate "
                  f"{row['crash_rate']:.2f}, coverage {row['coverage']:.2f}, diversity "
                  f"{row['diversity']:.2f} labels", flush=True)


class EpisodesCounted(BaseCallback):
    """Counts the training episodes that end (the ``dones`` of every step of every env):
    the count after Ctrl-C, when the envs' Monitors in the stopped workers cannot be asked
    and SB3's own count is kept by off-policy algorithms only."""

    def __init__(self) -> None:
        super().__init__(0)
        self.episodes = 0

    def _on_step(self) -> bool:
        self.episodes += int(np.count_nonzero(self.locals["dones"]))
        return True


class StepsAnnounced(BaseCallback):
    """Announces the training's progress every tenth of ``timesteps`` (steps done, wall
    time), so a long training says where it is whether or not on a terminal.

    Args:
        timesteps: the training's length (env steps over all envs).
        announce: called with one line each time.
    """

    def __init__(self, timesteps: int, announce: Callable[[str], None]) -> None:
        super().__init__(0)
        self.timesteps = timesteps
        self.announce = announce
        self._step = max(1, -(-timesteps // 10))
        self._next = self._step
        self._start = 0.0

    def _on_training_start(self) -> None:
        self._start = time.perf_counter()

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next and self.num_timesteps < self.timesteps:
            self.announce(f"trained {self.num_timesteps} of {self.timesteps} steps "
                          f"({time.perf_counter() - self._start:.0f} s)")
            self._next = self._step * (self.num_timesteps // self._step + 1)
        return True
